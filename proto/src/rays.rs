//! The cameras as a network's input (the trainer's `--camera-rays`): each patch's
//! Plücker rays in view 0's frame, the camera conditioning that lets global attention relate
//! two views' tokens by their epipolar geometry (as in multi-view diffusion and LRM-style
//! reconstruction networks). A ray through pixel (u, v) of a camera is its unit direction d
//! and its moment o × d, o the camera's centre over `scale` (the scene's median depth, so
//! that the input does not depend on the room's size); each patch gives the rays of k × k
//! sub-patch centres, `6·k²` values a token.

use crate::Camera;

/// Values a token gets from `k` × `k` rays.
pub fn ray_channels(k: usize) -> usize {
    6 * k * k
}

/// `[N, (height / patch)·(width / patch), 6·k²]`, row-major over the patches of an input of
/// `size` (height, width), of the cameras of the N input views in the frame of the first
/// (whatever frame they are given in); `scale` > 0 divides the camera centres.
pub fn patch_rays(
    cameras: &[Camera],
    [height, width]: [usize; 2],
    patch: usize,
    k: usize,
    scale: f32,
) -> Vec<f32> {
    let (rows, columns) = (height / patch, width / patch);
    let mut out = Vec::with_capacity(cameras.len() * rows * columns * ray_channels(k));
    let Some(reference) = cameras.first() else { return out };
    for cam in cameras {
        let origin = reference.world_to_camera(cam.center()) / scale;
        let rotation = reference.rotation * cam.rotation.inverse();
        for (py, px) in (0..rows).flat_map(|y| (0..columns).map(move |x| (y, x))) {
            for (sy, sx) in (0..k).flat_map(|y| (0..k).map(move |x| (y, x))) {
                let u = (px * patch) as f32 + (sx as f32 + 0.5) * patch as f32 / k as f32;
                let v = (py * patch) as f32 + (sy as f32 + 0.5) * patch as f32 / k as f32;
                let d = (rotation * cam.unproject(u, v, 1.0)).normalize();
                let m = origin.cross(d);
                out.extend([d.x, d.y, d.z, m.x, m.y, m.z]);
            }
        }
    }
    out
}

/// Median of the positive values of `depth` (the valid ground truth), `None` if there are
/// none.
pub fn median_depth(depth: &[f32]) -> Option<f32> {
    let mut valid: Vec<f32> = depth.iter().copied().filter(|d| *d > 0.0 && d.is_finite()).collect();
    if valid.is_empty() {
        return None;
    }
    let mid = valid.len() / 2;
    let (_, median, _) = valid.select_nth_unstable_by(mid, f32::total_cmp);
    Some(*median)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use glam::Vec3;

    /// A point that two cameras both see lies on a ray of each: the rays' reciprocal product
    /// d₁·m₂ + d₂·m₁ of two rays that meet is zero, and it is not for rays that miss.
    #[test]
    fn rays_through_one_point_meet_and_others_do_not() {
        let k = Intrinsics::from_fov_y(16, 16, 1.0);
        let a = Camera::look_at(k, Vec3::ZERO, Vec3::new(0.0, 0.0, 3.0), Vec3::NEG_Y);
        let b = Camera::look_at(k, Vec3::new(1.0, 0.2, 0.5), Vec3::new(0.0, 0.0, 3.0), Vec3::NEG_Y);
        let rays = patch_rays(&[a, b], [16, 16], 8, 2, 2.0);
        assert_eq!(rays.len(), 2 * 4 * ray_channels(2));
        // The centre of a's patch 0, sub-ray 0 (pixel 2, 2) at depth 2.5, seen by b.
        let p = a.camera_to_world(a.unproject(2.0, 2.0, 2.5));
        let (u, v) = b.project(b.world_to_camera(p));
        let ray = |cam: &Camera, u: f32, v: f32| {
            let d = (cam.rotation.inverse() * cam.unproject(u, v, 1.0)).normalize();
            (d, (cam.center() / 2.0).cross(d))
        };
        let reciprocal = |(d1, m1): (Vec3, Vec3), (d2, m2): (Vec3, Vec3)| d1.dot(m2) + d2.dot(m1);
        let ra = (Vec3::from_slice(&rays[0..3]), Vec3::from_slice(&rays[3..6]));
        assert!(reciprocal(ra, ray(&b, u, v)).abs() < 1e-5);
        assert!(reciprocal(ra, ray(&b, u + 3.0, v)).abs() > 1e-3);
        assert!(
            (ra.0 - ray(&a, 2.0, 2.0).0).length() < 1e-6,
            "sub-ray 0 of patch 0 passes pixel (2, 2)"
        );
    }

    /// The rays are the same whatever world frame the cameras are given in: they are
    /// re-expressed in the first camera's frame.
    #[test]
    fn rays_do_not_depend_on_the_world_frame() {
        let k = Intrinsics::from_fov_y(16, 16, 1.0);
        let a =
            Camera::look_at(k, Vec3::new(0.3, -0.2, 0.1), Vec3::new(0.5, 0.0, 3.0), Vec3::NEG_Y);
        let b = Camera::look_at(k, Vec3::new(1.0, 0.2, 0.5), Vec3::new(0.0, 0.4, 3.0), Vec3::NEG_Y);
        let turn = glam::Quat::from_euler(glam::EulerRot::YXZ, 0.7, -0.3, 0.2);
        let shift = Vec3::new(4.0, -1.0, 2.5);
        // The world moved by p ↦ turn·p + shift: each camera's world→camera map composes with its
        // inverse.
        let moved = |c: &Camera| Camera {
            intrinsics: c.intrinsics,
            rotation: c.rotation * turn.inverse(),
            translation: c.translation - c.rotation * turn.inverse() * shift,
        };
        assert!((moved(&a).center() - (turn * a.center() + shift)).length() < 1e-5);
        let here = patch_rays(&[a, b], [16, 16], 8, 2, 2.0);
        let there = patch_rays(&[moved(&a), moved(&b)], [16, 16], 8, 2, 2.0);
        let worst = here.iter().zip(&there).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
        assert!(worst < 1e-5, "rays moved by {worst}");
        assert!(
            here[..ray_channels(2)].chunks(6).all(|r| r[3..].iter().all(|m| m.abs() < 1e-6)),
            "view 0's rays pass its centre, the origin"
        );
    }
}
