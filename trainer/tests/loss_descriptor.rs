//! L_desc, the descriptor term: its value worked out by hand, its gradient against finite
//! differences, its matches (a view identical to another matches every pixel to itself, and a
//! synthesized scene's matches see one point), and that descriptors made from the true point
//! each pixel sees score a low loss and match on registration's grid where others do not; the
//! same of the form whose negatives are registration's grid.

use burn::prelude::*;
use inssplat_trainer::loss::descriptor::{NEAR, TEMPERATURE, view_pairs};
use inssplat_trainer::loss::{
    DescriptorMatches, descriptor_grid_loss, descriptor_loss, descriptor_matches,
    descriptor_scores, registration_grid,
};

use crate::loss_instance::check_gradient;
use crate::loss_point_map::synthesized;

fn tensor(values: &[f32], shape: [usize; 4]) -> Tensor<4> {
    Tensor::from_data(TensorData::new(values.to_vec(), shape), &Device::flex())
}

fn loss(descriptors: Tensor<4>, matches: &DescriptorMatches) -> f64 {
    f64::from(descriptor_loss(descriptors, matches).unwrap().into_scalar::<f32>())
}

fn grid_loss(descriptors: Tensor<4>, matches: &DescriptorMatches, stride: usize) -> f64 {
    f64::from(descriptor_grid_loss(descriptors, matches, stride).unwrap().into_scalar::<f32>())
}

#[test]
fn loss_descriptor_is_infonce_both_ways_over_the_pairs_samples() {
    // Two views of 1×4 pixels, D = 2: view 0's pixels 0 and 3 match view 1's pixels 3 and 0.
    let (a0, a1, b0, b1) = ([1.0, 0.0], [0.0, 2.0], [0.8, 0.6], [-0.6, 0.8]);
    #[rustfmt::skip]
    let values = [
        a0[0], 0.0, 0.0, a1[0], a0[1], 0.0, 0.0, a1[1], // view 0: channel 0, channel 1 (a1 unnormalized)
        b1[0], 0.0, 0.0, b0[0], b1[1], 0.0, 0.0, b0[1], // view 1
    ];
    let descriptors = tensor(&values, [2, 2, 1, 4]);
    let matches = DescriptorMatches { a: vec![0, 3], b: vec![4 + 3, 4], offsets: vec![0, 2] };
    // Cosines: a0·b0 0.8, a0·b1 −0.6, a1·b0 0.6, a1·b1 0.8.
    let cos = [[0.8, -0.6], [0.6, 0.8]];
    let ce = |logits: [f64; 2], target: usize| {
        let l = logits.map(|x| x / TEMPERATURE);
        (l[0].exp() + l[1].exp()).ln() - l[target]
    };
    let rows = ce(cos[0], 0) + ce(cos[1], 1);
    let columns = ce([cos[0][0], cos[1][0]], 0) + ce([cos[0][1], cos[1][1]], 1);
    let want = 0.5 * (rows + columns) / 2.0;
    let got = loss(descriptors.clone(), &matches);
    assert!((got - want).abs() < 1e-4 * want, "L_desc {got}, expected {want}");
    // Samples within NEAR pixels of each other are not negatives: each is alone, the loss 0.
    const { assert!(NEAR >= 1.0) };
    let near = DescriptorMatches { a: vec![0, 1], b: vec![4 + 3, 4 + 2], offsets: vec![0, 2] };
    assert!(loss(descriptors.clone(), &near).abs() < 1e-6);
    // No matches: zero; a match outside the map: a named error.
    assert_eq!(
        loss(descriptors.clone(), &DescriptorMatches { offsets: vec![0], ..Default::default() }),
        0.0
    );
    let outside = DescriptorMatches { a: vec![0], b: vec![8], offsets: vec![0, 1] };
    let err = descriptor_loss(descriptors, &outside).unwrap_err();
    assert!(err.to_string().contains("descriptor map"), "{err}");
}

/// Three views' descriptors, 3 channels of 4 pixels each (as 1×4 or 2×2), for the
/// finite-difference checks.
#[rustfmt::skip]
const VALUES: [f32; 36] = [
    0.3, -0.7, 1.1, 0.2, -0.4, 0.9, 0.5, 0.1, -1.2, 0.6, 0.8, -0.3, // view 0
    0.7, 0.4, -0.6, 1.3, 0.2, -0.9, 1.0, -0.2, 0.3, 0.5, -0.8, 0.6, // view 1
    -0.5, 0.9, 0.2, 0.4, 1.1, -0.3, 0.6, 0.7, -0.1, 0.2, 0.9, -0.6, // view 2
];

#[test]
fn loss_descriptor_gradient_matches_finite_differences() {
    // Pairs (0, 1) with three samples 3 pixels apart, (0, 2) with one, (1, 2) with two.
    let matches = DescriptorMatches {
        a: vec![0, 3, 0, 0, 4, 4 + 3],
        b: vec![4 + 3, 4, 4 + 1, 8 + 2, 8, 8 + 3],
        offsets: vec![0, 3, 4, 6],
    };
    check_gradient(&VALUES, [3, 3, 1, 4], |x| descriptor_loss(x, &matches).unwrap());
}

#[test]
fn registration_grid_starts_half_a_stride_in() {
    assert_eq!(registration_grid(6, 8, 4), vec![2 * 8 + 2, 2 * 8 + 6]);
    assert_eq!(registration_grid(2, 3, 1).len(), 6);
    assert_eq!(registration_grid(1, 5, 2), Vec::<usize>::new());
}

#[test]
fn loss_descriptor_grid_is_the_cross_entropy_of_the_grid_points_near_the_match() {
    // Two views of 2×8 pixels, D = 2; stride 2: the grid is pixels 1, 3, 5 and 7 of row 1.
    // View 0's pixel (0, 0) matches view 1's (6, 0): b's grid points at x 5 and 7 are
    // positives, 1 and 3 negatives; from b, a's grid point at x 1 is the one positive.
    let values: Vec<f32> = (0..2 * 2 * 16)
        .map(|i| {
            let (v, c, p) = (i / 32, (i / 16) % 2, i % 16);
            let angle = 0.37 * p as f32 + 1.3 * v as f32;
            if c == 0 { angle.cos() } else { 1.5 * angle.sin() }
        })
        .collect();
    let descriptors = tensor(&values, [2, 2, 2, 8]);
    let unit = |v: usize, p: usize| {
        let (c, s) = (f64::from(values[v * 32 + p]), f64::from(values[v * 32 + 16 + p]));
        let n = (c * c + s * s).sqrt();
        (c / n, s / n)
    };
    let grid = [9, 11, 13, 15];
    let term = |query: (f64, f64), view: usize, positives: &[usize]| {
        let exp = |p: usize| {
            let key = unit(view, p);
            ((query.0 * key.0 + query.1 * key.1) / TEMPERATURE).exp()
        };
        let all: f64 = grid.iter().map(|&p| exp(p)).sum();
        let pos: f64 = positives.iter().map(|&p| exp(p)).sum();
        -(pos / all).ln()
    };
    let matches = DescriptorMatches { a: vec![0], b: vec![16 + 6], offsets: vec![0, 1] };
    let want = 0.5 * (term(unit(0, 0), 1, &[13, 15]) + term(unit(1, 6), 0, &[9]));
    let got = grid_loss(descriptors.clone(), &matches, 2);
    assert!((got - want).abs() < 1e-4 * want, "L_desc on the grid {got}, expected {want}");
    // No matches: zero; a match outside the map or a view smaller than the grid: named errors.
    assert_eq!(
        grid_loss(
            descriptors.clone(),
            &DescriptorMatches { offsets: vec![0], ..Default::default() },
            2
        ),
        0.0
    );
    let outside = DescriptorMatches { a: vec![0], b: vec![32], offsets: vec![0, 1] };
    assert!(
        descriptor_grid_loss(descriptors.clone(), &outside, 2)
            .unwrap_err()
            .to_string()
            .contains("descriptor map")
    );
    let err = descriptor_grid_loss(descriptors, &matches, 4).unwrap_err();
    assert!(err.to_string().contains("registration grid"), "{err}");
}

#[test]
fn loss_descriptor_grid_gradient_matches_finite_differences() {
    // Stride 1: every pixel a grid point, those within one pixel positives. Pair (1, 2) empty.
    let matches =
        DescriptorMatches { a: vec![0, 3, 1], b: vec![4 + 3, 4, 8 + 2], offsets: vec![0, 2, 3, 3] };
    check_gradient(&VALUES, [3, 3, 2, 2], |x| descriptor_grid_loss(x, &matches, 1).unwrap());
}

#[test]
fn descriptor_matches_see_one_point_in_both_views() {
    let size = 64;
    let hw = size * size;
    let (_dir, scene) = synthesized(3, size as u32, size as u32, 16, (0.5, 0.6));
    let depth = |f: usize| scene.frames[f].depth.clone().unwrap();
    // One view twice: every sample matches itself.
    let same = [scene.frames[0].camera, scene.frames[0].camera];
    let m = descriptor_matches(&same, &[depth(0), depth(0)].concat(), size, 100).unwrap();
    assert_eq!((m.pairs(), m.len()), (1, 100));
    assert!(m.a.iter().zip(&m.b).all(|(&a, &b)| b == a + hw), "{m:?}");
    // Three views along the path: each pair's samples see one world point, within a few pixels'
    // footprint.
    let frames = [0, 2, 4];
    let cameras: Vec<_> = frames.iter().map(|&f| scene.frames[f].camera).collect();
    let all_depth: Vec<f32> = frames.iter().flat_map(|&f| depth(f)).collect();
    let m = descriptor_matches(&cameras, &all_depth, size, 50).unwrap();
    assert_eq!(m.pairs(), 3);
    assert!(m.pair(0).len() == 50 && m.pair(1).len() > 10, "{:?}", m.offsets);
    let world = |i: usize| {
        let (v, p) = (i / hw, i % hw);
        let cam = cameras[v];
        let cam = inssplat_proto::Camera {
            intrinsics: cam.intrinsics.scaled_to(size as u32, size as u32),
            ..cam
        };
        cam.camera_to_world(cam.unproject(
            (p % size) as f32 + 0.5,
            (p / size) as f32 + 0.5,
            all_depth[i],
        ))
    };
    let mut moved = 0;
    for (&a, &b) in m.a.iter().zip(&m.b) {
        let (pa, pb) = (world(a), world(b));
        let z = all_depth[a];
        assert!((pa - pb).length() < 0.05 * z, "sample {a} sees {pa}, its match {b} sees {pb}");
        moved += usize::from(a % hw != b % hw);
    }
    assert!(
        moved > m.len() / 2,
        "{moved} of {} matches moved: the views are not the same",
        m.len()
    );
}

#[test]
fn turned_at_least_keeps_only_the_pairs_that_turn_that_much() {
    let size = 64;
    let (_dir, scene) = synthesized(3, size as u32, size as u32, 16, (0.5, 0.6));
    let frames = [0, 2, 4, 0];
    let cameras: Vec<_> = frames.iter().map(|&f| scene.frames[f].camera).collect();
    let depth: Vec<f32> =
        frames.iter().flat_map(|&f| scene.frames[f].depth.clone().unwrap()).collect();
    let m = descriptor_matches(&cameras, &depth, size, 20).unwrap();
    let angle = |k: usize| {
        let (a, b) = view_pairs(4).nth(k).unwrap();
        cameras[a].rotation.angle_between(cameras[b].rotation)
    };
    // Pair (0, 3) sees one camera twice: it turns by nothing and goes first.
    assert!(angle(2) < 1e-3 && !m.pair(2).is_empty());
    let min = angle(0).max(angle(1)).min(0.5) * 0.99;
    let kept = m.turned_at_least(&cameras, min);
    assert_eq!(kept.pairs(), m.pairs());
    for k in 0..m.pairs() {
        let want = if angle(k) >= min { m.pair(k).len() } else { 0 };
        assert_eq!(kept.pair(k).len(), want, "pair {k} turns {} rad", angle(k));
        assert_eq!(&kept.a[kept.pair(k)], if want > 0 { &m.a[m.pair(k)] } else { &[][..] });
    }
    assert!(kept.len() < m.len() && !kept.is_empty(), "{} of {} samples kept", kept.len(), m.len());
    assert_eq!(m.turned_at_least(&cameras, 0.0), m);
}

/// D = 16 random Fourier features of the world point each pixel of `frames` sees.
fn true_point_descriptors(
    scene: &inssplat_proto::dataset::Scene,
    frames: &[usize],
    size: usize,
) -> Vec<f32> {
    let hw = size * size;
    let mut out = vec![0.0f32; frames.len() * 16 * hw];
    let directions: Vec<glam::Vec3> = (0..8)
        .map(|k| {
            let k = k as f32;
            glam::Vec3::new((1.7 * k + 0.3).sin(), (2.3 * k + 1.1).cos(), (0.9 * k + 2.0).sin())
                * 6.0
        })
        .collect();
    for (v, &f) in frames.iter().enumerate() {
        let frame = &scene.frames[f];
        let cam = inssplat_proto::Camera {
            intrinsics: frame.camera.intrinsics.scaled_to(size as u32, size as u32),
            ..frame.camera
        };
        let depth = frame.depth.as_ref().unwrap();
        for p in 0..hw {
            let point = cam.camera_to_world(cam.unproject(
                (p % size) as f32 + 0.5,
                (p / size) as f32 + 0.5,
                depth[p].max(0.1),
            ));
            for (k, dir) in directions.iter().enumerate() {
                out[(v * 16 + 2 * k) * hw + p] = dir.dot(point).sin();
                out[(v * 16 + 2 * k + 1) * hw + p] = dir.dot(point).cos();
            }
        }
    }
    out
}

#[test]
fn descriptors_of_the_true_point_match_and_others_do_not() {
    let size = 64;
    let (_dir, scene) = synthesized(5, size as u32, size as u32, 16, (0.5, 0.6));
    let frames = [0, 2];
    let cameras: Vec<_> = frames.iter().map(|&f| scene.frames[f].camera).collect();
    let depth: Vec<f32> =
        frames.iter().flat_map(|&f| scene.frames[f].depth.clone().unwrap()).collect();
    let matches = descriptor_matches(&cameras, &depth, size, 64).unwrap();
    assert!(matches.len() > 20, "{} matches", matches.len());
    let dims = [2, 16, size, size];
    let truth = true_point_descriptors(&scene, &frames, size);
    // The same descriptors with view 1's pixels shuffled (each row moved by 37 pixels).
    let hw = size * size;
    let mut shuffled = truth.clone();
    for c in 0..16 {
        for p in 0..hw {
            shuffled[(16 + c) * hw + p] = truth[(16 + c) * hw + (p * 37 + 11) % hw];
        }
    }
    let good = descriptor_scores(&truth, dims, &matches, 4);
    let bad = descriptor_scores(&shuffled, dims, &matches, 4);
    assert!(good.within_stride > 0.8, "{good:?}");
    assert!(bad.within_stride < 0.2, "{bad:?}");
    let (l_good, l_bad) =
        (loss(tensor(&truth, dims), &matches), loss(tensor(&shuffled, dims), &matches));
    assert!(
        l_good < 0.5 * l_bad,
        "L_desc {l_good} of the true point's descriptors against {l_bad} shuffled"
    );
    let (l_good, l_bad) = (
        grid_loss(tensor(&truth, dims), &matches, 4),
        grid_loss(tensor(&shuffled, dims), &matches, 4),
    );
    assert!(
        l_good < 0.5 * l_bad,
        "L_desc on the grid {l_good} of the true point's descriptors against {l_bad} shuffled"
    );
}
