//! Adam (Kingma & Ba, 2015) over flat parameter slices: the optimizer of the test-time
//! refinements (a target camera's pose in [`crate::target_pose`], a scene's Gaussians and
//! context cameras in [`crate::refine`]).

use glam::{Quat, Vec3};
use inssplat_proto::Camera;

use inssplat_raster::render::CameraGrad;

const BETA1: f32 = 0.9;
const BETA2: f32 = 0.999;
const EPSILON: f32 = 1e-12;

/// Adam's moments for one group of parameters.
#[derive(Debug, Clone, Default)]
pub struct Adam {
    t: i32,
    m: Vec<f32>,
    v: Vec<f32>,
}

impl Adam {
    /// Moments for `len` parameters.
    pub fn new(len: usize) -> Self {
        Self { t: 0, m: vec![0.0; len], v: vec![0.0; len] }
    }

    /// One step: parameter `i` moves by its learning rate `lrs[i % lrs.len()]` (one rate for
    /// the whole group, or one per component of a repeated record).
    ///
    /// # Panics
    /// If `params` or `grads` do not have the group's length, or `lrs` is empty.
    pub fn step(&mut self, params: &mut [f32], grads: &[f32], lrs: &[f32]) {
        assert_eq!(params.len(), self.m.len(), "parameter count differs from the optimizer's");
        assert_eq!(grads.len(), self.m.len(), "gradient count differs from the optimizer's");
        assert!(!lrs.is_empty(), "no learning rate");
        self.t += 1;
        let (c1, c2) = (1.0 - BETA1.powi(self.t), 1.0 - BETA2.powi(self.t));
        for (i, ((p, &g), (m, v))) in
            params.iter_mut().zip(grads).zip(self.m.iter_mut().zip(&mut self.v)).enumerate()
        {
            *m = BETA1 * *m + (1.0 - BETA1) * g;
            *v = BETA2 * *v + (1.0 - BETA2) * g * g;
            *p -= lrs[i % lrs.len()] * (*m / c1) / ((*v / c2).sqrt() + EPSILON);
        }
    }
}

/// Adam on a camera's world → camera pose: its quaternion's components at `lr_rotation` (the
/// quaternion renormalized after the step) and its translation at `lr_translation`.
#[derive(Debug, Clone)]
pub struct PoseAdam(Adam);

impl Default for PoseAdam {
    fn default() -> Self {
        Self(Adam::new(7))
    }
}

impl PoseAdam {
    pub fn step(
        &mut self,
        camera: &mut Camera,
        grad: &CameraGrad,
        lr_rotation: f32,
        lr_translation: f32,
    ) {
        let (q, t) = (camera.rotation, camera.translation);
        let mut pose = [q.w, q.x, q.y, q.z, t.x, t.y, t.z];
        let [gw, gx, gy, gz] = grad.rotation;
        let [tx, ty, tz] = grad.translation;
        let (r, t) = (lr_rotation, lr_translation);
        self.0.step(&mut pose, &[gw, gx, gy, gz, tx, ty, tz], &[r, r, r, r, t, t, t]);
        camera.rotation = Quat::from_xyzw(pose[1], pose[2], pose[3], pose[0]).normalize();
        camera.translation = Vec3::new(pose[4], pose[5], pose[6]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adam_finds_the_minimum_of_a_quadratic_at_each_rate() {
        // f(x) = Σ (x_i − c_i)², two rates cycled over four parameters.
        let c = [1.0, -2.0, 0.5, 3.0];
        let mut x = [0.0f32; 4];
        let mut adam = Adam::new(4);
        for _ in 0..3000 {
            let g: Vec<f32> = x.iter().zip(&c).map(|(x, c)| 2.0 * (x - c)).collect();
            adam.step(&mut x, &g, &[1e-2, 2e-2]);
        }
        for (x, c) in x.iter().zip(&c) {
            assert!((x - c).abs() < 1e-2, "{x} vs {c}");
        }
    }

    #[test]
    fn the_first_step_moves_each_parameter_by_its_rate() {
        // Bias correction makes Adam's first step lr · sign(g), whatever the gradient's size.
        let mut x = [0.0f32, 0.0];
        Adam::new(2).step(&mut x, &[1e-4, -30.0], &[0.1, 0.01]);
        assert!((x[0] + 0.1).abs() < 1e-6 && (x[1] - 0.01).abs() < 1e-6, "{x:?}");
    }
}
