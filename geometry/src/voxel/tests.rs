use super::*;

fn push(s: &mut GaussianScene, mean: [f32; 3], log_scale: [f32; 3], conf: f32, emb: f32, sem: f32) {
    let mut e = [0.0; INSTANCE_DIM];
    e[0] = emb;
    e[1] = 1.0 - emb;
    s.push(Gaussian {
        mean,
        log_scale,
        rotation: [1.0, 0.0, 0.0, 0.0],
        logit_opacity: logit(0.5),
        sh_dc: [conf, 0.0, 0.0],
        confidence: conf,
        instance_embedding: e,
        semantic: &[sem],
        instance_id: 0,
    });
}

/// A scene of 100 Gaussians on a 10×10 grid in [0, 9]² (extent 9 in x and y; the 5–95
/// percentiles are 0 and 9 → extent 9), plus what a test adds.
fn grid() -> GaussianScene {
    let mut s = GaussianScene::with_sem_dim(1);
    for i in 0..100 {
        push(&mut s, [(i % 10) as f32, (i / 10) as f32, 0.0], [-3.0; 3], 1.0, 1.0, 0.0);
    }
    s
}

#[test]
fn robust_extent_ignores_outliers() {
    let mut s = grid();
    push(&mut s, [1000.0, 0.0, 0.0], [0.0; 3], 1.0, 1.0, 0.0);
    assert_eq!(robust_extent(&s.means), 9.0);
}

#[test]
fn two_gaussians_in_one_voxel_merge_with_confidence_weights() {
    let mut s = grid();
    // Voxel size 9/9 = 1: both land in voxel (20, 20, 20) with weights 1/4 and 3/4.
    push(&mut s, [20.1, 20.5, 20.5], [-3.0; 3], 1.0, 1.0, 4.0);
    push(&mut s, [20.5, 20.5, 20.5], [-3.0; 3], 3.0, 0.0, 8.0);
    let params = VoxelParams {
        extent_fraction: 1.0 / 9.0,
        opacity: OpacityMerge::Mean,
        ..VoxelParams::default()
    };
    let Voxelized { scene: out, report, voxel_of } = voxelize(&s, &params).unwrap();
    assert_eq!((report.gaussians_in, report.gaussians_out, report.voxel_size), (102, 101, 1.0));
    let m = out.means.iter().position(|m| m[0] > 15.0).unwrap();
    assert_eq!((voxel_of[100], voxel_of[101]), (m as u32, m as u32));
    assert!((out.means[m][0] - (0.25 * 20.1 + 0.75 * 20.5)).abs() < 1e-5);
    assert_eq!(out.sh_dc[m][0], 0.25 * 1.0 + 0.75 * 3.0);
    assert_eq!(out.confidence[m], 4.0);
    assert_eq!(out.semantic_of(m), &[7.0]);
    assert!((sigmoid(out.logit_opacity[m]) - 0.5).abs() < 1e-5);
    assert_eq!(&out.instance_embedding[m][..2], &[0.25, 0.75]);
    // Covariance: isotropic e^-6 plus the spread of the means along x:
    // Σ w d² = 0.25·0.3² + 0.75·0.1² = 0.03.
    let var: Vec<f32> = out.log_scales[m].iter().map(|l| (2.0 * l).exp()).collect();
    let mut sorted = var.clone();
    sorted.sort_by(f32::total_cmp);
    let base = (-6.0f32).exp();
    assert!((sorted[2] - (base + 0.03)).abs() < 1e-5, "{var:?}");
    assert!((sorted[0] - base).abs() < 1e-5 && (sorted[1] - base).abs() < 1e-5, "{var:?}");
    let back = covariance(out.log_scales[m], out.rotations[m]);
    assert!((back.x_axis.x - (base + 0.03)).abs() < 1e-5, "the long axis is x: {back}");
}

#[test]
fn coverage_opacity_keeps_a_stacks_composite_and_a_rows_own_opacity() {
    let coverage = VoxelParams {
        extent_fraction: 1.0 / 9.0,
        opacity: OpacityMerge::Coverage,
        ..VoxelParams::default()
    };
    let merged = |s: &GaussianScene| {
        let out = voxelize(s, &coverage).unwrap().scene;
        let m = out.means.iter().position(|m| m[0] > 15.0).unwrap();
        sigmoid(out.logit_opacity[m])
    };
    // Three members of α 0.5 on one spot: the composite 1 − 0.5³.
    let mut stack = grid();
    for conf in [1.0, 2.0, 3.0] {
        push(&mut stack, [20.5, 20.5, 20.5], [-3.0; 3], conf, 1.0, 0.0);
    }
    assert!((merged(&stack) - 0.875).abs() < 1e-4, "{}", merged(&stack));
    // Two flat members (scales e^-1, e^-1, e^-6) side by side along x, 0.6 apart: the
    // merged footprint is the moment-matched one, its opacity the members' optical depth
    // spread over it, and the mean rule would have kept 0.5.
    let mut row = grid();
    for x in [20.2, 20.8] {
        push(&mut row, [x, 20.5, 20.5], [-1.0, -1.0, -6.0], 1.0, 1.0, 0.0);
    }
    let (s1, var_x) = ((-1.0f32).exp(), (-2.0f32).exp() + 0.09);
    let expected = 1.0 - (-2.0 * 2f32.ln() * s1 * s1 / (var_x.sqrt() * s1)).exp();
    assert!((merged(&row) - expected).abs() < 1e-4, "{} vs {expected}", merged(&row));
    assert!(expected > 0.5 && expected < 0.75);
}

#[test]
fn softmax_weighting_prefers_the_confident_member() {
    let mut s = grid();
    push(&mut s, [20.1, 20.5, 20.5], [-3.0; 3], 1.0, 1.0, 0.0);
    push(&mut s, [20.5, 20.5, 20.5], [-3.0; 3], 1.0 + 2f32.ln(), 1.0, 0.0);
    let params = VoxelParams {
        extent_fraction: 1.0 / 9.0,
        weighting: Weighting::Softmax { temperature: 1.0 },
        ..VoxelParams::default()
    };
    let out = voxelize(&s, &params).unwrap().scene;
    let m = out.means.iter().position(|m| m[0] > 15.0).unwrap();
    // Weights e^0 : e^ln2 = 1/3 : 2/3.
    assert!((out.means[m][0] - (20.1 / 3.0 + 2.0 * 20.5 / 3.0)).abs() < 1e-5);
}

#[test]
fn rotated_covariances_survive_the_round_trip() {
    let q = Quat::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 2.0);
    let ls = [-1.0, 0.5, -2.0];
    let cov = covariance(ls, [q.w, q.x, q.y, q.z]);
    let (ls2, r2) = scale_rotation(cov).unwrap();
    let back = covariance(ls2, r2);
    assert!((back - cov).abs().to_cols_array().iter().all(|d| *d < 1e-5), "{back} vs {cov}");
    let mut a = ls.to_vec();
    let mut b = ls2.to_vec();
    a.sort_by(f32::total_cmp);
    b.sort_by(f32::total_cmp);
    assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-4), "{a:?} vs {b:?}");
    let [w, x, y, z] = r2;
    assert!((Quat::from_xyzw(x, y, z, w).length() - 1.0).abs() < 1e-5);
}

#[test]
fn drops_transparent_and_non_finite_and_rejects_bad_params() {
    let mut s = grid();
    push(&mut s, [f32::NAN, 0.0, 0.0], [0.0; 3], 1.0, 1.0, 0.0);
    push(&mut s, [3.0, 3.0, 3.0], [0.0; 3], 1.0, 1.0, 0.0);
    *s.logit_opacity.last_mut().unwrap() = logit(0.001);
    // An infinite scale and a zero rotation, both in grid point (1, 1)'s voxel.
    push(&mut s, [1.0, 1.0, 0.0], [f32::INFINITY, 0.0, 0.0], 1.0, 1.0, 0.0);
    push(&mut s, [1.0, 1.0, 0.0], [0.0; 3], 1.0, 1.0, 0.0);
    *s.rotations.last_mut().unwrap() = [0.0; 4];
    let Voxelized { scene: mut out, report, voxel_of } =
        voxelize(&s, &VoxelParams::default()).unwrap();
    assert_eq!((report.dropped, out.len()), (4, 100));
    // The dropped ones point nowhere and take id 0; the others take their voxel's id.
    assert_eq!(&voxel_of[100..], &[DROPPED; 4]);
    out.instance_id = (1..=100).collect();
    let merged = Voxelized { scene: out, report, voxel_of };
    let ids = merged.input_instance_ids();
    assert_eq!(&ids[100..], &[0; 4]);
    let mut kept = ids[..100].to_vec();
    kept.sort_unstable();
    assert_eq!(kept, (1..=100).collect::<Vec<u32>>(), "one grid point per voxel, each its own id");
    let out = merged.scene;
    assert!(out.log_scales.iter().flatten().all(|l| *l == -3.0));
    assert_eq!(scale_rotation(Mat3::from_diagonal(Vec3::new(f32::NAN, 1.0, 1.0))), None);
    let bad = VoxelParams { extent_fraction: 0.0, ..VoxelParams::default() };
    assert_eq!(voxelize(&s, &bad).unwrap_err(), VoxelError::Fraction(0.0));
    s.confidence.pop();
    assert!(matches!(voxelize(&s, &VoxelParams::default()), Err(VoxelError::Scene(_))));
}

#[test]
fn merged_gaussians_adopt_their_members_majority_id() {
    let mut s = grid();
    // Three members in voxel (20, 20, 20), two in (30, 30, 30), one dropped.
    for x in [20.1, 20.4, 20.7] {
        push(&mut s, [x, 20.5, 20.5], [-3.0; 3], 1.0, 1.0, 0.0);
    }
    for x in [30.2, 30.6] {
        push(&mut s, [x, 30.5, 30.5], [-3.0; 3], 1.0, 1.0, 0.0);
    }
    push(&mut s, [f32::NAN, 0.0, 0.0], [0.0; 3], 1.0, 1.0, 0.0);
    let params = VoxelParams { extent_fraction: 1.0 / 9.0, ..VoxelParams::default() };
    let mut merged = voxelize(&s, &params).unwrap();
    merged.scene.instance_id = vec![9; merged.scene.len()];
    let (a, b) = (merged.voxel_of[100] as usize, merged.voxel_of[103] as usize);
    assert_eq!(
        (merged.voxel_of[102] as usize, merged.voxel_of[104] as usize, merged.voxel_of[105]),
        (a, b, DROPPED)
    );
    // The grid keeps its own ids; the triple votes 2 against 1 for id 5, the pair ties
    // between 7 and 4 (the smaller wins), and the dropped member's vote counts nowhere.
    let mut input: Vec<u32> = (0..100).map(|i| i % 3).collect();
    input.extend([5, 3, 5, 7, 4, 1]);
    merged.adopt_member_majority(&input);
    assert_eq!((merged.scene.instance_id[a], merged.scene.instance_id[b]), (5, 4));
    let ids = merged.input_instance_ids();
    assert_eq!(&ids[..100], &input[..100], "a voxel of one member takes that member's id");
    assert_eq!(&ids[100..], &[5, 5, 5, 4, 4, 0]);
}
