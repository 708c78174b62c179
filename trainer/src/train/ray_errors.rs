//! The camera errors a network that reads its cameras ([`crate::model::ModelConfig::camera_rays`])
//! is shown: each camera turned about its own centre (validation's `--ray-noise`, and the
//! training run's, as registration errs), and the rays left out (`--ray-dropout`, so that one
//! network runs both without cameras, to register them, and with them).

use glam::{Quat, Vec3};
use inssplat_proto::Camera;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::sample::{RayCameras, Sample};

/// What the rays a training sample gives the network are.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct RayPlan {
    /// Share of samples whose rays are all zero (the network's input before registration).
    pub dropout: f32,
    /// Every other sample's cameras but view 0's are turned about their centres by an angle
    /// drawn uniformly up to this many degrees, each about its own random axis.
    pub noise_deg: f32,
}

impl RayPlan {
    /// Sets `sample`'s rays by the plan; `index` (the sample's in the run) seeds the draw.
    pub fn apply(&self, sample: &mut Sample, index: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(index ^ 0x5241_5953);
        if rng.random::<f32>() < self.dropout {
            sample.ray_cameras = RayCameras::Dropped;
        } else if self.noise_deg > 0.0 {
            let max = self.noise_deg;
            sample.ray_cameras =
                RayCameras::Given(turn_each(&sample.cameras[..sample.inputs], &mut rng, |rng| {
                    rng.random_range(0.0..=max)
                }));
        }
    }
}

/// `cameras` with every one after the first turned by `degrees` about its own centre, each
/// about an axis drawn from `seed` (the first, the world frame, stays): the camera errors a
/// network that reads its cameras would get from registration.
pub(super) fn turned(cameras: &[Camera], degrees: f32, seed: u64) -> Vec<Camera> {
    if degrees == 0.0 {
        return cameras.to_vec();
    }
    turn_each(cameras, &mut ChaCha8Rng::seed_from_u64(seed), |_| degrees)
}

/// `cameras` with every one after the first turned about its own centre by `degrees(rng)`
/// about a uniformly random axis.
fn turn_each(
    cameras: &[Camera],
    rng: &mut ChaCha8Rng,
    degrees: impl Fn(&mut ChaCha8Rng) -> f32,
) -> Vec<Camera> {
    let mut out = cameras.to_vec();
    for cam in out.iter_mut().skip(1) {
        let (z, phi): (f32, f32) =
            (rng.random_range(-1.0..1.0), rng.random_range(0.0..std::f32::consts::TAU));
        let r = (1.0 - z * z).sqrt();
        let turn = Quat::from_axis_angle(
            Vec3::new(r * phi.cos(), r * phi.sin(), z),
            degrees(rng).to_radians(),
        );
        let centre = cam.center();
        cam.rotation = turn * cam.rotation;
        cam.translation = -(cam.rotation * centre);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use inssplat_proto::Intrinsics;

    fn cameras() -> Vec<Camera> {
        let k = Intrinsics::from_fov_y(16, 16, 1.0);
        (0..4)
            .map(|i| {
                Camera::look_at(
                    k,
                    Vec3::new(i as f32, 0.3, -1.0),
                    Vec3::new(0.0, 0.0, 3.0),
                    Vec3::NEG_Y,
                )
            })
            .collect()
    }

    /// The plan drops about its share of samples' rays, turns every other sample's cameras
    /// but view 0's by no more than its angle (and by different angles), and draws the same
    /// for the same sample index.
    #[test]
    fn a_ray_plan_drops_its_share_and_turns_within_its_angle() {
        let plan = RayPlan { dropout: 0.25, noise_deg: 20.0 };
        let sample = Sample {
            scene: "s".into(),
            inputs: 3,
            size: 16,
            images: vec![],
            depth: vec![],
            ids: vec![],
            cameras: cameras(),
            teacher: vec![],
            vocabulary: vec![],
            shell: vec![],
            ray_cameras: RayCameras::True,
        };
        let (mut dropped, mut angles) = (0, Vec::new());
        for index in 0..400 {
            let mut s = sample.clone();
            plan.apply(&mut s, index);
            let mut again = sample.clone();
            plan.apply(&mut again, index);
            assert_eq!(s.ray_cameras, again.ray_cameras);
            match s.ray_cameras {
                RayCameras::Dropped => dropped += 1,
                RayCameras::Given(turned) => {
                    assert_eq!(turned.len(), 3, "the input views' cameras");
                    assert_eq!(turned[0], sample.cameras[0]);
                    angles.extend(
                        turned
                            .iter()
                            .zip(&sample.cameras)
                            .skip(1)
                            .map(|(a, b)| a.rotation.angle_between(b.rotation).to_degrees()),
                    );
                }
                RayCameras::True => panic!("a plan with noise turns every sample it keeps"),
            }
        }
        assert!((70..130).contains(&dropped), "{dropped} of 400 dropped at 0.25");
        assert!(angles.iter().all(|&a| a <= 20.01), "{angles:?}");
        let mean = angles.iter().sum::<f32>() / angles.len() as f32;
        assert!((8.0..12.0).contains(&mean), "uniform up to 20°: mean {mean}");
        let mut keep = sample.clone();
        RayPlan::default().apply(&mut keep, 3);
        assert_eq!(keep.ray_cameras, RayCameras::True, "an empty plan keeps the true cameras");
    }

    /// Every camera but the first turns by the angle asked, about its own centre.
    #[test]
    fn turned_cameras_keep_their_centres_and_turn_by_the_angle() {
        let cameras = cameras();
        let out = turned(&cameras, 7.0, 5);
        assert_eq!(out[0], cameras[0]);
        for (a, b) in cameras.iter().zip(&out).skip(1) {
            assert!((a.center() - b.center()).length() < 1e-5);
            assert!((a.rotation.angle_between(b.rotation).to_degrees() - 7.0).abs() < 1e-2);
        }
        assert_eq!(turned(&cameras, 0.0, 5), cameras);
    }
}
