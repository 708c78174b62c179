//! Shape descriptors of instances: where the floor is, and each instance's size, height
//! above the floor and colour ([`inssplat_proto::shape::DESCRIPTOR`]), from 3D points alone.
//! The same code describes the trainer's ground-truth objects (points back-projected from
//! true depth) and the server's clustered Gaussians, so the shape classifier meets at
//! inference the descriptors it was fitted on. [`fuse`] turns the classifier's probabilities
//! into a text-space direction and adds it to an instance's semantic prototype.
//!
//! The floor is found by RANSAC among the lowest points for the plane whose normal is within
//! [`MAX_TILT_DEG`] of the cameras' mean up direction (photos are taken roughly level, but
//! often pitched down: the cameras alone would tilt every height by the pitch).

use glam::Vec3;
use inssplat_proto::gaussian::sh_dc_to_rgb;
use inssplat_proto::shape::DESCRIPTOR;
use inssplat_proto::{Camera, GaussianScene};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{InstancePrototype, add_direction, normalized};

/// Largest angle between the floor's normal and the cameras' up direction.
pub const MAX_TILT_DEG: f32 = 40.0;
/// Fewest points an instance needs for a descriptor.
pub const MIN_POINTS: usize = 8;

/// The floor plane: a point's height is `up · p − floor`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ground {
    pub up: Vec3,
    pub floor: f32,
    /// Whether a floor plane was found (otherwise `up` is the cameras' and `floor` the
    /// lowest points' height).
    pub found: bool,
}

impl Ground {
    pub fn height(&self, p: Vec3) -> f32 {
        self.up.dot(p) - self.floor
    }
}

/// The cameras' mean up direction in the world (OpenCV: a camera's up is its −y axis).
pub fn camera_up(cameras: &[Camera]) -> Vec3 {
    let sum: Vec3 = cameras.iter().map(|c| c.rotation.inverse() * Vec3::NEG_Y).sum();
    sum.try_normalize().unwrap_or(Vec3::NEG_Y)
}

/// `q`-quantile (0–1) of `v`, reordering it.
fn quantile(v: &mut [f32], q: f32) -> f32 {
    let k = ((v.len() - 1) as f32 * q).round() as usize;
    *v.select_nth_unstable_by(k, f32::total_cmp).1
}

/// Finds the floor among `points` (any order, any density), starting from `up_prior`.
pub fn ground(points: &[Vec3], up_prior: Vec3) -> Ground {
    let up_prior = up_prior.try_normalize().unwrap_or(Vec3::NEG_Y);
    let mut rng = ChaCha8Rng::seed_from_u64(0x9_0d);
    let step = (points.len() / 4000).max(1);
    let sample: Vec<Vec3> =
        points.iter().step_by(step).copied().filter(|p| p.is_finite()).collect();
    if sample.len() < 3 {
        return Ground { up: up_prior, floor: 0.0, found: false };
    }
    let mut heights: Vec<f32> = sample.iter().map(|p| up_prior.dot(*p)).collect();
    let lowest = quantile(&mut heights, 0.02);
    let range = (quantile(&mut heights, 0.98) - lowest).max(1e-6);
    let fallback = Ground { up: up_prior, floor: lowest, found: false };
    let low: Vec<Vec3> =
        sample.iter().copied().filter(|p| up_prior.dot(*p) < lowest + 0.35 * range).collect();
    if low.len() < 3 {
        return fallback;
    }
    let tol = 0.02 * range;
    let cos_tilt = MAX_TILT_DEG.to_radians().cos();
    let mut best = (0usize, fallback);
    for _ in 0..256 {
        let [a, b, c] = [0; 3].map(|_| low[rng.random_range(0..low.len())]);
        let Some(mut n) = (b - a).cross(c - a).try_normalize() else { continue };
        if n.dot(up_prior) < 0.0 {
            n = -n;
        }
        if n.dot(up_prior) < cos_tilt {
            continue;
        }
        let d = n.dot(a);
        let (mut below, mut inliers) = (0usize, 0usize);
        for p in &sample {
            let h = n.dot(*p) - d;
            if h < -3.0 * tol {
                below += 1;
            } else if h.abs() < tol {
                inliers += 1;
            }
        }
        // A floor has (almost) nothing below it.
        if below * 20 > sample.len() {
            continue;
        }
        if inliers > best.0 {
            best = (inliers, Ground { up: n, floor: d, found: true });
        }
    }
    if best.0 * 20 < sample.len() {
        return fallback;
    }
    best.1
}

/// The descriptor of one instance from its points and their colours (RGB in [0, 1]);
/// `None` under [`MIN_POINTS`].
pub fn descriptor(
    points: &[Vec3],
    colors: &[[f32; 3]],
    ground: &Ground,
) -> Option<[f32; DESCRIPTOR.len()]> {
    if points.len() < MIN_POINTS || points.len() != colors.len() {
        return None;
    }
    let up = ground.up;
    let e1 = up.any_orthonormal_vector();
    let e2 = up.cross(e1);
    let mut h: Vec<f32> = points.iter().map(|p| ground.height(*p)).collect();
    let (bottom, top) = (quantile(&mut h, 0.02), quantile(&mut h, 0.98));
    // Principal axes of the footprint (closed-form 2×2 eigenvectors).
    let flat: Vec<[f32; 2]> = points.iter().map(|p| [e1.dot(*p), e2.dot(*p)]).collect();
    let n = flat.len() as f32;
    let m = flat.iter().fold([0.0; 2], |s, q| [s[0] + q[0] / n, s[1] + q[1] / n]);
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for q in &flat {
        let (x, y) = (q[0] - m[0], q[1] - m[1]);
        sxx += x * x;
        syy += y * y;
        sxy += x * y;
    }
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let axes = [[angle.cos(), angle.sin()], [-angle.sin(), angle.cos()]];
    let extent = |a: [f32; 2]| {
        let mut v: Vec<f32> = flat.iter().map(|q| q[0] * a[0] + q[1] * a[1]).collect();
        quantile(&mut v, 0.98) - quantile(&mut v, 0.02)
    };
    let (e_a, e_b) = (extent(axes[0]), extent(axes[1]));
    let mean: [f32; 3] = std::array::from_fn(|c| colors.iter().map(|x| x[c]).sum::<f32>() / n);
    let spread: [f32; 3] = std::array::from_fn(|c| {
        (colors.iter().map(|x| (x[c] - mean[c]).powi(2)).sum::<f32>() / n).sqrt()
    });
    Some([
        top - bottom,
        e_a.max(e_b),
        e_a.min(e_b),
        bottom,
        top,
        mean[0],
        mean[1],
        mean[2],
        spread[0],
        spread[1],
        spread[2],
    ])
}

/// The descriptor of every instance id of `scene` (ids in order; ids with too few Gaussians
/// left out), with the floor found on all of the scene's Gaussians.
pub fn instance_descriptors(
    scene: &GaussianScene,
    cameras: &[Camera],
) -> (Ground, Vec<(u32, [f32; DESCRIPTOR.len()])>) {
    let points: Vec<Vec3> = scene.means.iter().map(|m| Vec3::from_array(*m)).collect();
    let ground = ground(&points, camera_up(cameras));
    let k = scene.instance_id.iter().copied().max().unwrap_or(0) as usize;
    let mut members: Vec<(Vec<Vec3>, Vec<[f32; 3]>)> = vec![(Vec::new(), Vec::new()); k];
    for ((p, sh), &id) in points.iter().zip(&scene.sh_dc).zip(&scene.instance_id) {
        if id > 0 {
            let m = &mut members[id as usize - 1];
            m.0.push(*p);
            m.1.push(sh.map(|f| sh_dc_to_rgb(f).clamp(0.0, 1.0)));
        }
    }
    let out = members
        .iter()
        .enumerate()
        .filter_map(|(i, (p, c))| descriptor(p, c, &ground).map(|d| (i as u32 + 1, d)))
        .collect();
    (ground, out)
}

/// Adds `weight` × the unit text-space direction Σ p_k·t̂_k (the classifier's probabilities
/// over its labels, whose text embeddings are `label_texts`) to each prototype whose id has
/// probabilities, and normalizes again.
pub fn fuse<T: AsRef<[f32]>>(
    prototypes: &mut [InstancePrototype],
    probabilities: &[(u32, Vec<f32>)],
    label_texts: &[T],
    weight: f32,
) {
    let texts: Vec<Vec<f32>> = label_texts.iter().map(|t| normalized(t.as_ref())).collect();
    for p in prototypes.iter_mut() {
        let Some((_, probs)) = probabilities.iter().find(|(id, _)| *id == p.id) else { continue };
        let mut dir = vec![0.0f32; p.embedding.len()];
        for (t, &w) in texts.iter().zip(probs) {
            dir.iter_mut().zip(t).for_each(|(d, x)| *d += w * x);
        }
        add_direction(p, &normalized(&dir), weight);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    /// A floor grid at height 0 (y up), plus a 0.5 × 1.0 × 2.0 box standing on it.
    fn room(tilt: Quat) -> (Vec<Vec3>, Vec<Vec3>) {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let floor: Vec<Vec3> = (0..3000)
            .map(|_| Vec3::new(rng.random_range(-3.0..3.0), 0.0, rng.random_range(-3.0..3.0)))
            .collect();
        let object: Vec<Vec3> = (0..2000)
            .map(|_| {
                Vec3::new(
                    rng.random_range(0.0..2.0),
                    rng.random_range(0.0..1.0),
                    rng.random_range(0.0..0.5),
                )
            })
            .collect();
        let walls: Vec<Vec3> = (0..2000)
            .map(|_| Vec3::new(3.0, rng.random_range(0.0..2.5), rng.random_range(-3.0..3.0)))
            .collect();
        let all = floor.iter().chain(&object).chain(&walls).map(|p| tilt * *p).collect();
        (all, object.iter().map(|p| tilt * *p).collect())
    }

    #[test]
    fn the_floor_is_found_under_a_tilted_prior_and_sizes_are_measured_from_it() {
        let turn = Quat::from_rotation_x(0.7) * Quat::from_rotation_z(0.3);
        let (all, object) = room(turn);
        let true_up = turn * Vec3::Y;
        // A prior 25° off (cameras pitched down).
        let prior = turn * Quat::from_rotation_z(25f32.to_radians()) * Vec3::Y;
        let g = ground(&all, prior);
        assert!(g.found);
        assert!(g.up.angle_between(true_up).to_degrees() < 1.0, "{:?} vs {true_up:?}", g.up);
        let colors = vec![[0.2, 0.4, 0.6]; object.len()];
        let d = descriptor(&object, &colors, &g).unwrap();
        let close = |a: f32, b: f32| (a - b).abs() < 0.1;
        assert!(close(d[0], 1.0) && close(d[1], 2.0) && close(d[2], 0.5), "{d:?}");
        assert!(close(d[3], 0.0) && close(d[4], 1.0), "{d:?}");
        assert!(close(d[5], 0.2) && close(d[7], 0.6) && d[8] < 1e-4, "{d:?}");
        // Measured from the prior alone, the 25° pitch would shear the box.
        let level = Ground { found: false, ..g };
        let tilted = descriptor(&object, &colors, &Ground { up: prior, ..level }).unwrap();
        assert!(tilted[0] > 1.3, "{tilted:?}");
    }

    #[test]
    fn without_a_floor_the_prior_and_the_lowest_points_stand_in() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let blob: Vec<Vec3> = (0..1000)
            .map(|_| {
                Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
            })
            .filter(|p| p.length() < 1.0)
            .collect();
        let g = ground(&blob, Vec3::Y);
        assert!(!g.found);
        assert_eq!(g.up, Vec3::Y);
        assert!(descriptor(&blob[..3], &[[0.0; 3]; 3], &g).is_none());
    }

    #[test]
    fn fusing_moves_a_prototype_toward_the_likely_label() {
        let mut protos =
            vec![InstancePrototype { id: 2, embedding: vec![1.0, 0.0, 0.0], gaussians: 5 }];
        let texts = [vec![0.0, 2.0, 0.0], vec![0.0, 0.0, 1.0]];
        fuse(&mut protos, &[(2, vec![0.9, 0.1])], &texts, 3.0);
        let e = &protos[0].embedding;
        assert!(e[1] > e[0] && e[1] > e[2], "{e:?}");
        assert!((e.iter().map(|x| x * x).sum::<f32>() - 1.0).abs() < 1e-5);
        // An id without probabilities keeps its prototype.
        let mut other =
            vec![InstancePrototype { id: 3, embedding: vec![1.0, 0.0, 0.0], gaussians: 5 }];
        fuse(&mut other, &[(2, vec![0.9, 0.1])], &texts, 3.0);
        assert_eq!(other[0].embedding, [1.0, 0.0, 0.0]);
    }
}
