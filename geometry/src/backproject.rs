//! Back-projection: the network's per-pixel outputs (depth, depth confidence, the 14 Gaussian
//! channels, instance embedding S, semantic feature L; see `inssplat_proto::signature`) and the
//! predicted camera of each view become one world-space `GaussianScene`, one Gaussian per
//! valid pixel. The pixel's centre is lifted to its depth along the camera z axis, the
//! predicted camera-frame offset is added, and the camera-frame rotation is turned into the
//! world frame; scale, opacity, colour, S and L are copied as they are. Pixels whose depth is
//! not a positive finite number carry no surface and are skipped; every Gaussian remembers its
//! pixel, so per-Gaussian results map back onto the views ([`BackProjected::to_pixels`]).

use glam::{Quat, Vec3};
use inssplat_proto::gaussian::Gaussian;
use inssplat_proto::signature::GAUSSIAN_CHANNELS;
use inssplat_proto::{Camera, GaussianScene, INSTANCE_DIM};
use rayon::prelude::*;

/// One view's network outputs, planar `[C][H][W]` slices for `H`×`W` = the camera's image
/// size, and the view's predicted camera.
#[derive(Debug, Clone, Copy)]
pub struct ViewOutputs<'a> {
    pub camera: &'a Camera,
    /// `[1][H][W]`, metres along the camera z axis.
    pub depth: &'a [f32],
    /// `[1][H][W]`, > 0, larger is surer.
    pub depth_conf: &'a [f32],
    /// `[14][H][W]`: offset xyz, log-scale xyz, rotation w,x,y,z (camera frame), opacity
    /// logit, SH DC rgb.
    pub gaussians: &'a [f32],
    /// `[8][H][W]`, instance embedding S.
    pub instance: &'a [f32],
    /// `[d_s][H][W]`, semantic feature L.
    pub semantic: &'a [f32],
}

/// Why outputs cannot be back-projected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BackprojectError {
    #[error(
        "view {view}: `{tensor}` has {actual} values, expected {expected} ({channels} channels of {width}×{height})"
    )]
    Shape {
        view: usize,
        tensor: &'static str,
        actual: usize,
        expected: usize,
        channels: usize,
        width: u32,
        height: u32,
    },
}

/// [`backproject`]'s result.
#[derive(Debug, Clone, PartialEq)]
pub struct BackProjected {
    /// One Gaussian per valid pixel, view by view, each view in row-major pixel order;
    /// `instance_id` is 0.
    pub scene: GaussianScene,
    /// The pixel of each Gaussian, counted over all views: view · H·W + row · W + column.
    pub pixel: Vec<u32>,
    /// Pixels of all views.
    pub pixels: usize,
}

impl BackProjected {
    /// One value per Gaussian (`values[i]` for Gaussian i) laid out on the views' pixels,
    /// `[V][H][W]`; 0 at pixels that made no Gaussian.
    pub fn to_pixels(&self, values: &[u32]) -> Vec<u32> {
        let mut out = vec![0; self.pixels];
        for (&p, &v) in self.pixel.iter().zip(values) {
            out[p as usize] = v;
        }
        out
    }

    /// The Gaussians of every `stride`-th pixel across and down each view (`width` ×
    /// `height` pixels), each grown by `stride`, so that they cover the views as before when
    /// rendered at 1/`stride` of their resolution: a cheap stand-in for comparing renders at
    /// that size. Only what a colour render reads is kept (no embeddings or features).
    pub fn thinned(&self, width: u32, height: u32, stride: u32) -> GaussianScene {
        let (w, per_view, stride) =
            (width as usize, (width * height) as usize, stride.max(1) as usize);
        let grow = (stride as f32).ln();
        let mut out = GaussianScene::with_sem_dim(0);
        let s = &self.scene;
        for (i, &p) in self.pixel.iter().enumerate() {
            let local = p as usize % per_view;
            if !(local % w).is_multiple_of(stride) || !(local / w).is_multiple_of(stride) {
                continue;
            }
            out.push(Gaussian {
                mean: s.means[i],
                log_scale: s.log_scales[i].map(|l| l + grow),
                rotation: s.rotations[i],
                logit_opacity: s.logit_opacity[i],
                sh_dc: s.sh_dc[i],
                confidence: s.confidence[i],
                instance_embedding: [0.0; INSTANCE_DIM],
                semantic: &[],
                instance_id: 0,
            });
        }
        out
    }
}

/// Back-projects every view into one scene whose semantic features have `sem_dim` channels.
pub fn backproject(
    views: &[ViewOutputs<'_>],
    sem_dim: usize,
) -> Result<BackProjected, BackprojectError> {
    for (v, view) in views.iter().enumerate() {
        check_shapes(v, view, sem_dim)?;
    }
    let parts: Vec<(GaussianScene, Vec<u32>)> =
        views.par_iter().map(|view| backproject_view(view, sem_dim)).collect();
    let mut scene = GaussianScene::with_sem_dim(sem_dim);
    let total = parts.iter().map(|(s, _)| s.len()).sum();
    scene.reserve(total);
    let mut pixel = Vec::with_capacity(total);
    let mut offset = 0;
    for ((part, pixels), view) in parts.into_iter().zip(views) {
        scene.append(part);
        pixel.extend(pixels.iter().map(|p| offset + p));
        offset += view.camera.intrinsics.width * view.camera.intrinsics.height;
    }
    Ok(BackProjected { scene, pixel, pixels: offset as usize })
}

fn check_shapes(v: usize, view: &ViewOutputs<'_>, sem_dim: usize) -> Result<(), BackprojectError> {
    let (width, height) = (view.camera.intrinsics.width, view.camera.intrinsics.height);
    let pixels = width as usize * height as usize;
    let tensors = [
        ("depth", view.depth.len(), 1),
        ("depth_conf", view.depth_conf.len(), 1),
        ("gaussians", view.gaussians.len(), GAUSSIAN_CHANNELS),
        ("instance", view.instance.len(), INSTANCE_DIM),
        ("semantic", view.semantic.len(), sem_dim),
    ];
    for (tensor, actual, channels) in tensors {
        if actual != channels * pixels {
            return Err(BackprojectError::Shape {
                view: v,
                tensor,
                actual,
                expected: channels * pixels,
                channels,
                width,
                height,
            });
        }
    }
    Ok(())
}

/// One view's Gaussians and the pixel each came from.
fn backproject_view(view: &ViewOutputs<'_>, sem_dim: usize) -> (GaussianScene, Vec<u32>) {
    let cam = view.camera;
    let width = cam.intrinsics.width as usize;
    let pixels = width * cam.intrinsics.height as usize;
    let world_from_camera = cam.rotation.inverse();
    let gauss = |c: usize, p: usize| view.gaussians[c * pixels + p];
    let mut scene = GaussianScene::with_sem_dim(sem_dim);
    let valid = view.depth.iter().filter(|d| d.is_finite() && **d > 0.0).count();
    scene.reserve(valid);
    let mut from = Vec::with_capacity(valid);
    let mut semantic = vec![0.0; sem_dim];
    for p in 0..pixels {
        let z = view.depth[p];
        if !(z.is_finite() && z > 0.0) {
            continue;
        }
        let (u, v) = ((p % width) as f32 + 0.5, (p / width) as f32 + 0.5);
        let offset = Vec3::new(gauss(0, p), gauss(1, p), gauss(2, p));
        let mean = cam.camera_to_world(cam.unproject(u, v, z) + offset);
        let q_cam = Quat::from_xyzw(gauss(7, p), gauss(8, p), gauss(9, p), gauss(6, p));
        let q_cam = if q_cam.length_squared() > 1e-20 { q_cam.normalize() } else { Quat::IDENTITY };
        let q = (world_from_camera * q_cam).normalize();
        let mut embedding = [0.0; INSTANCE_DIM];
        for (k, e) in embedding.iter_mut().enumerate() {
            *e = view.instance[k * pixels + p];
        }
        for (k, s) in semantic.iter_mut().enumerate() {
            *s = view.semantic[k * pixels + p];
        }
        scene.push(inssplat_proto::gaussian::Gaussian {
            mean: mean.to_array(),
            log_scale: [gauss(3, p), gauss(4, p), gauss(5, p)],
            rotation: [q.w, q.x, q.y, q.z],
            logit_opacity: gauss(10, p),
            sh_dc: [gauss(11, p), gauss(12, p), gauss(13, p)],
            confidence: view.depth_conf[p],
            instance_embedding: embedding,
            semantic: &semantic,
            instance_id: 0,
        });
        from.push(p as u32);
    }
    (scene, from)
}

#[cfg(test)]
mod tests {
    use super::*;
    use inssplat_proto::Intrinsics;

    /// A 2×2 view with constant planar channels except where a test overrides them.
    struct Planes {
        depth: Vec<f32>,
        conf: Vec<f32>,
        gaussians: Vec<f32>,
        instance: Vec<f32>,
        semantic: Vec<f32>,
    }

    fn planes(sem_dim: usize) -> Planes {
        let px = 4;
        let mut gaussians = vec![0.0; GAUSSIAN_CHANNELS * px];
        gaussians[6 * px..7 * px].fill(1.0); // rotation w
        Planes {
            depth: vec![2.0; px],
            conf: vec![1.5; px],
            gaussians,
            instance: (0..INSTANCE_DIM * px).map(|i| i as f32).collect(),
            semantic: (0..sem_dim * px).map(|i| -(i as f32)).collect(),
        }
    }

    fn view<'a>(cam: &'a Camera, p: &'a Planes) -> ViewOutputs<'a> {
        ViewOutputs {
            camera: cam,
            depth: &p.depth,
            depth_conf: &p.conf,
            gaussians: &p.gaussians,
            instance: &p.instance,
            semantic: &p.semantic,
        }
    }

    fn k() -> Intrinsics {
        Intrinsics { fx: 2.0, fy: 2.0, cx: 1.0, cy: 1.0, width: 2, height: 2 }
    }

    #[test]
    fn identity_camera_lifts_pixel_centres_and_copies_features() {
        let cam = Camera { intrinsics: k(), rotation: Quat::IDENTITY, translation: Vec3::ZERO };
        let mut p = planes(2);
        p.depth[3] = 4.0;
        p.gaussians[1] = 0.25; // offset x (channel 0) of pixel 1
        let s = backproject(&[view(&cam, &p)], 2).unwrap().scene;
        assert_eq!(s.len(), 4);
        // Pixel (0, 0): centre (0.5, 0.5), (u − cx)/fx · z = −0.25 · 2.
        assert_eq!(s.means[0], [-0.5, -0.5, 2.0]);
        assert_eq!(s.means[1], [0.5 + 0.25, -0.5, 2.0]);
        assert_eq!(s.means[3], [1.0, 1.0, 4.0]);
        assert_eq!(s.confidence[2], 1.5);
        assert_eq!(s.instance_embedding[1], [1.0, 5.0, 9.0, 13.0, 17.0, 21.0, 25.0, 29.0]);
        assert_eq!(s.semantic_of(2), &[-2.0, -6.0]);
        assert!(s.validate().is_ok());
    }

    #[test]
    fn rotated_camera_maps_points_and_rotations_to_world() {
        let eye = Vec3::new(3.0, 1.0, -2.0);
        let cam = Camera::look_at(k(), eye, Vec3::new(0.0, 1.0, 0.0), Vec3::Y);
        let mut p = planes(1);
        // A camera-frame rotation of 90° about the camera z axis, unnormalized (×2).
        let q_cam = Quat::from_rotation_z(std::f32::consts::FRAC_PI_2) * 2.0;
        for (c, v) in [(6, q_cam.w), (7, q_cam.x), (8, q_cam.y), (9, q_cam.z)] {
            p.gaussians[c * 4] = v;
        }
        let s = backproject(&[view(&cam, &p)], 1).unwrap().scene;
        // Re-projecting each mean lands on its pixel centre at its depth.
        for (i, m) in s.means.iter().enumerate() {
            let pc = cam.world_to_camera(Vec3::from(*m));
            let (u, v) = cam.project(pc);
            assert!(
                (u - ((i % 2) as f32 + 0.5)).abs() < 1e-4
                    && (v - ((i / 2) as f32 + 0.5)).abs() < 1e-4
            );
            assert!((pc.z - 2.0).abs() < 1e-4);
        }
        // The world rotation, seen from the camera, is the camera-frame one.
        let [w, x, y, z] = s.rotations[0];
        let back = cam.rotation * Quat::from_xyzw(x, y, z, w);
        assert!(back.dot(q_cam.normalize()).abs() > 1.0 - 1e-5, "{back:?}");
    }

    #[test]
    fn skips_invalid_depth_and_rejects_bad_shapes() {
        let cam = Camera { intrinsics: k(), rotation: Quat::IDENTITY, translation: Vec3::ZERO };
        let mut p = planes(1);
        p.depth[0] = 0.0;
        p.depth[1] = f32::NAN;
        p.gaussians[6 * 4 + 2] = 0.0; // zero quaternion → identity
        let b = backproject(&[view(&cam, &p), view(&cam, &p)], 1).unwrap();
        assert_eq!(b.scene.len(), 4);
        assert_eq!(b.scene.rotations[0], [1.0, 0.0, 0.0, 0.0]);
        // Each Gaussian knows its pixel; the skipped pixels get 0 when values go back.
        assert_eq!((b.pixel.as_slice(), b.pixels), ([2, 3, 6, 7].as_slice(), 8));
        assert_eq!(b.to_pixels(&[1, 2, 3, 4]), [0, 0, 1, 2, 0, 0, 3, 4]);
        p.semantic.pop();
        let err = backproject(&[view(&cam, &planes(1)), view(&cam, &p)], 1).unwrap_err();
        assert!(
            matches!(err, BackprojectError::Shape { view: 1, tensor: "semantic", .. }),
            "{err}"
        );
    }
}
