//! The rays left out of a training sample of a network that reads its cameras
//! ([`crate::model::ModelConfig::camera_rays`], `--ray-dropout`), so that one network runs both
//! without cameras, to register them, and with them.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::sample::{RayCameras, Sample};

/// What the rays a training sample gives the network are. Plans saved with a `noise_deg`
/// (cameras turned as registration errs, an experiment since removed) read without it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct RayPlan {
    /// Share of samples whose rays are all zero (the network's input before registration).
    pub dropout: f32,
}

impl RayPlan {
    /// Sets `sample`'s rays by the plan; `index` (the sample's in the run) seeds the draw.
    pub fn apply(&self, sample: &mut Sample, index: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(index ^ 0x5241_5953);
        if rng.random::<f32>() < self.dropout {
            sample.ray_cameras = RayCameras::Dropped;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plan drops about its share of samples' rays, keeps the true cameras of the others,
    /// and draws the same for the same sample index.
    #[test]
    fn a_ray_plan_drops_its_share() {
        let plan = RayPlan { dropout: 0.25 };
        let sample = Sample {
            scene: "s".into(),
            inputs: 3,
            size: 16,
            images: vec![],
            depth: vec![],
            ids: vec![],
            cameras: vec![],
            teacher: vec![],
            vocabulary: vec![],
            shell: vec![],
            ray_cameras: RayCameras::True,
        };
        let mut dropped = 0;
        for index in 0..400 {
            let mut s = sample.clone();
            plan.apply(&mut s, index);
            let mut again = sample.clone();
            plan.apply(&mut again, index);
            assert_eq!(s.ray_cameras, again.ray_cameras);
            match s.ray_cameras {
                RayCameras::Dropped => dropped += 1,
                RayCameras::True => {}
            }
        }
        assert!((70..130).contains(&dropped), "{dropped} of 400 dropped at 0.25");
        let mut keep = sample.clone();
        RayPlan::default().apply(&mut keep, 3);
        assert_eq!(keep.ray_cameras, RayCameras::True, "an empty plan keeps the true cameras");
    }

    /// A plan saved with the ray noise of an earlier trainer still reads.
    #[test]
    fn a_saved_plan_with_ray_noise_reads_as_its_dropout() {
        let plan: RayPlan = serde_json::from_str(r#"{"dropout":0.25,"noise_deg":20.0}"#).unwrap();
        assert_eq!(plan, RayPlan { dropout: 0.25 });
    }
}
