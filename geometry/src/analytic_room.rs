//! A small analytic room for the tests and benchmark of the post-processing chain: a floor with
//! four
//! boxes (two "chair"s, a "table", a "cabinet"), seen by cameras on a ring, rendered exactly
//! by ray–box intersection per pixel centre into an `inssplat_proto::dataset::Scene` (depth,
//! instance ids, colour). [`ideal_outputs`] gives what a perfect network would output for it
//! (`crate::ideal`, with the room's exact surface normals and labels), and the
//! semantic code's Φ_sem projection lands on its label's (random, unit) text embedding.
//! The geometry and eval crates' tests and `eval/benches/post.rs` use it; the same chain runs
//! on synthesized scenes in the workspace's `tests/tests/chain_synth.rs`.

use crate::ideal::{ViewPlanes, ideal_view, label_projection, pixel_ray};
use glam::Vec3;
use inssplat_proto::dataset::{Frame, InstanceLabel, Scene};
use inssplat_proto::signature::TEXT_DIM;
use inssplat_proto::{Camera, Intrinsics};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Half the floor's side; the floor is the square |x|, |z| ≤ FLOOR at y = 0 (background).
const FLOOR: f32 = 3.4;

/// The room's boxes: (min, max, instance id, label).
const BOXES: [([f32; 3], [f32; 3], u16, &str); 4] = [
    ([-1.2, 0.0, -0.9], [0.9, 0.9, 0.8], 1, "table"),
    ([-2.9, 0.0, -2.8], [-1.4, 1.3, -1.3], 2, "chair"),
    ([1.2, 0.0, 1.0], [2.7, 1.3, 2.5], 3, "chair"),
    ([-3.0, 0.0, 0.7], [-1.6, 2.0, 2.7], 4, "cabinet"),
];

/// Label of the floor (background, instance id 0): in the vocabulary, never a ground-truth
/// instance.
pub const FLOOR_LABEL: &str = "floor";

/// The vocabulary: every label of the room, the floor's, and distractors.
pub const VOCABULARY: [&str; 8] =
    ["table", "chair", "cabinet", FLOOR_LABEL, "lamp", "sofa", "bed", "plant"];

/// Width of the semantic feature L.
pub const SEM_DIM: usize = VOCABULARY.len();

/// A ray's first hit: distance along the unit direction, surface normal, instance id, label.
struct Hit {
    t: f32,
    normal: Vec3,
    id: u16,
    label: &'static str,
}

fn cast(origin: Vec3, dir: Vec3) -> Option<Hit> {
    let mut best: Option<Hit> = None;
    if dir.y < -1e-6 {
        let t = -origin.y / dir.y;
        let p = origin + t * dir;
        if p.x.abs() <= FLOOR && p.z.abs() <= FLOOR {
            best = Some(Hit { t, normal: Vec3::Y, id: 0, label: FLOOR_LABEL });
        }
    }
    for (min, max, id, label) in BOXES {
        let (min, max) = (Vec3::from(min), Vec3::from(max));
        let inv = dir.recip();
        let (a, b) = ((min - origin) * inv, (max - origin) * inv);
        let (near, far) = (a.min(b), a.max(b));
        let t_near = near.max_element();
        if t_near > far.min_element()
            || t_near <= 0.0
            || best.as_ref().is_some_and(|h| h.t <= t_near)
        {
            continue;
        }
        // The entry face is the axis whose slab was entered last.
        let axis = (0..3).find(|&k| near[k] == t_near).unwrap_or(0);
        let mut normal = Vec3::ZERO;
        normal[axis] = -dir[axis].signum();
        best = Some(Hit { t: t_near, normal, id, label });
    }
    best
}

/// `views` cameras on a ring of radius 7 around the room (34° field of view, `size`×`size`
/// pixels), each looking at the room's centre from a height of 5 to 5.6.
pub fn ring_cameras(views: usize, size: u32) -> Vec<Camera> {
    let k = Intrinsics::from_fov_y(size, size, 34f32.to_radians());
    (0..views)
        .map(|i| {
            let a = 0.3 + i as f32 * std::f32::consts::TAU / views as f32;
            let eye = Vec3::new(7.0 * a.cos(), 5.0 + 0.3 * (i % 3) as f32, 7.0 * a.sin());
            Camera::look_at(k, eye, Vec3::new(0.0, 0.3, 0.0), Vec3::Y)
        })
        .collect()
}

/// The room seen by `cameras`, rendered exactly: depth along the camera z axis (0 = no hit),
/// instance ids, flat colours.
pub fn render_scene(cameras: &[Camera]) -> Scene {
    let frames = cameras
        .iter()
        .map(|cam| {
            let (w, h) = (cam.intrinsics.width as usize, cam.intrinsics.height as usize);
            let mut rgb = vec![0u8; w * h * 3];
            let mut depth = vec![0.0; w * h];
            let mut instances = vec![0u16; w * h];
            for p in 0..w * h {
                let (o, d) = pixel_ray(cam, p % w, p / w);
                if let Some(hit) = cast(o, d) {
                    depth[p] = cam.world_to_camera(o + hit.t * d).z;
                    instances[p] = hit.id;
                    let shade =
                        0.6 + 0.4 * hit.normal.dot(Vec3::new(0.3, 0.9, 0.3).normalize()).abs();
                    let base = colour(hit.id);
                    for c in 0..3 {
                        rgb[3 * p + c] = (255.0 * base[c] * shade) as u8;
                    }
                }
            }
            Frame { camera: *cam, rgb, depth: Some(depth), instances: Some(instances) }
        })
        .collect();
    Scene {
        dir: Default::default(),
        instances: BOXES
            .iter()
            .map(|b| InstanceLabel { id: u32::from(b.2), label: b.3.to_string() })
            .collect(),
        frames,
        eval: None,
        depth_unit_m: inssplat_proto::dataset::DEFAULT_DEPTH_UNIT_M,
    }
}

fn colour(id: u16) -> [f32; 3] {
    [[0.5, 0.5, 0.45], [0.6, 0.3, 0.1], [0.2, 0.5, 0.8], [0.3, 0.7, 0.3], [0.8, 0.8, 0.2]]
        [usize::from(id) % 5]
}

/// Text embeddings of [`VOCABULARY`] (random unit vectors) and the Φ_sem that maps the
/// semantic code e_j to label j's vector: W's column j is that vector, b = 0.
pub struct TextSpace {
    pub vocabulary: Vec<Vec<f32>>,
    /// `[TEXT_DIM][SEM_DIM]` row-major.
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
}

pub fn text_space(seed: u64) -> TextSpace {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let vocabulary: Vec<Vec<f32>> = VOCABULARY
        .iter()
        .map(|_| {
            let v: Vec<f32> = (0..TEXT_DIM).map(|_| rng.random_range(-1.0f32..1.0)).collect();
            let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.into_iter().map(|x| x / n).collect()
        })
        .collect();
    let (weight, bias) = label_projection(&vocabulary);
    TextSpace { vocabulary, weight, bias }
}

/// Index of `label` in [`VOCABULARY`].
pub fn label_index(label: &str) -> usize {
    VOCABULARY.iter().position(|l| *l == label).expect("label in the vocabulary")
}

/// Ideal outputs ([`ideal_view`]) for every frame of `scene`, with the room's exact normals
/// and labels (the floor's included), and uniform noise of ±`noise` per code entry.
pub fn ideal_outputs(scene: &Scene, noise: f32, seed: u64) -> Vec<ViewPlanes> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut noise = || rng.random_range(-noise..=noise);
    scene
        .frames
        .iter()
        .map(|f| {
            let w = f.width() as usize;
            let hits: Vec<Option<Hit>> = (0..w * f.height() as usize)
                .map(|p| {
                    let (o, d) = pixel_ray(&f.camera, p % w, p / w);
                    cast(o, d)
                })
                .collect();
            let normal_at = |p: usize| hits[p].as_ref().map_or(Vec3::ZERO, |h| h.normal);
            let label_at = |p: usize| hits[p].as_ref().map(|h| label_index(h.label));
            ideal_view(f, normal_at, label_at, SEM_DIM, &mut noise)
        })
        .collect()
}

#[test]
fn ray_casting_matches_the_projected_geometry() {
    let cams = ring_cameras(4, 96);
    let scene = render_scene(&cams);
    for (f, cam) in scene.frames.iter().zip(&cams) {
        let (w, depth, ids) = (96, f.depth.as_ref().unwrap(), f.instances.as_ref().unwrap());
        // The table's top centre projects onto a table pixel at the right depth.
        let top = cam.world_to_camera(Vec3::new(-0.15, 0.9, -0.05));
        let (u, v) = cam.project(top);
        let p = v as usize * w + u as usize;
        assert_eq!(ids[p], 1);
        assert!((depth[p] - top.z).abs() < 0.05 * top.z, "{} vs {}", depth[p], top.z);
        // Every box is visible somewhere, and every hit has a positive depth.
        for id in 1..=4 {
            assert!(ids.contains(&id), "box {id} unseen");
        }
        assert!(
            depth.iter().all(|z| *z >= 0.0)
                && depth.iter().filter(|z| **z > 0.0).count() > w * w / 2
        );
    }
}
