//! What a perfect network would output for a view whose ground truth is known: true depth,
//! pixel-sized Gaussians lying in the surface, a noisy one-hot instance embedding of the true
//! instance and a noisy one-hot semantic code of the true label, with the Φ_sem that maps
//! code j onto label j's text embedding. Fed through back-projection, voxelization,
//! clustering, mask rendering and labelling, it proves the post-processing chain before any
//! network exists (the chain tests on an analytic room and on synthesized scenes, and the
//! post-processing benchmark).

use glam::{Mat3, Quat, Vec3};
use inssplat_proto::dataset::Frame;
use inssplat_proto::gaussian::{logit, rgb_to_sh_dc};
use inssplat_proto::signature::GAUSSIAN_CHANNELS;
use inssplat_proto::{Camera, INSTANCE_DIM};

use crate::backproject::ViewOutputs;

/// Standard deviation of an ideal Gaussian, in pixel footprints.
pub const SIGMA_PX: f32 = 0.4;

/// One view's ideal outputs, planar `[C][H][W]` as the network gives them.
pub struct ViewPlanes {
    pub depth: Vec<f32>,
    pub conf: Vec<f32>,
    pub gaussians: Vec<f32>,
    pub instance: Vec<f32>,
    pub semantic: Vec<f32>,
}

impl ViewPlanes {
    /// The planes as back-projection takes them, seen by `camera`.
    pub fn outputs<'a>(&'a self, camera: &'a Camera) -> ViewOutputs<'a> {
        ViewOutputs {
            camera,
            depth: &self.depth,
            depth_conf: &self.conf,
            gaussians: &self.gaussians,
            instance: &self.instance,
            semantic: &self.semantic,
        }
    }
}

/// World-space origin and unit direction of the ray through the centre of pixel (`x`, `y`).
pub fn pixel_ray(cam: &Camera, x: usize, y: usize) -> (Vec3, Vec3) {
    let p = cam.camera_to_world(cam.unproject(x as f32 + 0.5, y as f32 + 0.5, 1.0));
    let o = cam.center();
    (o, (p - o).normalize())
}

/// Ideal outputs for `frame` (which must carry depth and instance ids below
/// [`INSTANCE_DIM`]): its true depth (0 = no surface: nothing there); confidence
/// (1 + 4/z)·|cos| of the viewing angle; zero offsets; Gaussians flat in the surface whose
/// world normal at pixel p is `normal_at(p)`, [`SIGMA_PX`] pixel footprints wide (stretched by
/// 1/cos, at most ×1/0.35, along the ray's direction in the surface), opacity 0.98, the
/// pixel's colour; instance embedding e_id plus `noise()` per entry; semantic code
/// e_`label_at(p)` (zero where `None`) of `sem_dim` entries plus `noise()` per entry.
pub fn ideal_view(
    frame: &Frame,
    normal_at: impl Fn(usize) -> Vec3,
    label_at: impl Fn(usize) -> Option<usize>,
    sem_dim: usize,
    noise: &mut impl FnMut() -> f32,
) -> ViewPlanes {
    let cam = &frame.camera;
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let px = w * h;
    let depth = frame.depth.clone().expect("ideal outputs need depth");
    let ids = frame.instances.as_ref().expect("ideal outputs need instance ids");
    let mut v = ViewPlanes {
        conf: vec![0.0; px],
        gaussians: vec![0.0; GAUSSIAN_CHANNELS * px],
        instance: vec![0.0; INSTANCE_DIM * px],
        semantic: vec![0.0; sem_dim * px],
        depth,
    };
    for (p, &id) in ids.iter().enumerate() {
        let z = v.depth[p];
        if z <= 0.0 {
            continue;
        }
        let (_, d) = pixel_ray(cam, p % w, p / w);
        let normal = normal_at(p);
        // Surer when near and when facing the surface.
        v.conf[p] = (1.0 + 4.0 / z) * normal.dot(-d).abs().max(0.05);
        // A disc in the surface: along the ray's in-surface direction `a` it spans the
        // pixel's stretched footprint z/(f·cos), across it the plain one z/f.
        let (n_cam, d_cam) = (cam.rotation * normal, cam.rotation * d);
        let cos = n_cam.dot(d_cam).abs().max(0.35);
        let a = (d_cam - d_cam.dot(n_cam) * n_cam).normalize_or(n_cam.any_orthonormal_vector());
        let q = Quat::from_mat3(&Mat3::from_cols(a, n_cam.cross(a), n_cam));
        let s = SIGMA_PX * z / cam.intrinsics.fx;
        let rgb = [0, 1, 2].map(|c| f32::from(frame.rgb[3 * p + c]) / 255.0);
        let channels = [
            0.0,
            0.0,
            0.0,
            (s / cos).ln(),
            s.ln(),
            (0.05 * s).ln(),
            q.w,
            q.x,
            q.y,
            q.z,
            logit(0.98),
            rgb_to_sh_dc(rgb[0]),
            rgb_to_sh_dc(rgb[1]),
            rgb_to_sh_dc(rgb[2]),
        ];
        for (c, value) in channels.into_iter().enumerate() {
            v.gaussians[c * px + p] = value;
        }
        let id = usize::from(id);
        assert!(
            id < INSTANCE_DIM,
            "instance id {id} has no one-hot code in {INSTANCE_DIM} dimensions"
        );
        for k in 0..INSTANCE_DIM {
            v.instance[k * px + p] = f32::from(u8::from(k == id)) + noise();
        }
        let label = label_at(p);
        for k in 0..sem_dim {
            v.semantic[k * px + p] = f32::from(u8::from(Some(k) == label)) + noise();
        }
    }
    v
}

/// World-space unit surface normals of `frame` estimated from its depth: per pixel the cross
/// product of the steps to a horizontal and a vertical neighbour (on each axis the side whose
/// depth is closer, so edges take the normal of their own surface), turned to face the
/// camera; zero where the pixel or both neighbours on an axis have no depth.
pub fn depth_normals(frame: &Frame) -> Vec<Vec3> {
    let cam = &frame.camera;
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let depth = frame.depth.as_ref().expect("normals need depth");
    let point = |x: usize, y: usize| {
        let z = depth[y * w + x];
        (z > 0.0).then(|| cam.unproject(x as f32 + 0.5, y as f32 + 0.5, z))
    };
    // The step to the closer-in-depth neighbour of (x, y) along one axis, pointing forwards.
    let step = |centre: Vec3, before: Option<Vec3>, after: Option<Vec3>| match (before, after) {
        (Some(b), Some(a)) if (b.z - centre.z).abs() < (a.z - centre.z).abs() => Some(centre - b),
        (_, Some(a)) => Some(a - centre),
        (Some(b), None) => Some(centre - b),
        (None, None) => None,
    };
    (0..w * h)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            let Some(c) = point(x, y) else { return Vec3::ZERO };
            let dx = step(
                c,
                x.checked_sub(1).and_then(|x| point(x, y)),
                (x + 1 < w).then(|| point(x + 1, y)).flatten(),
            );
            let dy = step(
                c,
                y.checked_sub(1).and_then(|y| point(x, y)),
                (y + 1 < h).then(|| point(x, y + 1)).flatten(),
            );
            let (Some(dx), Some(dy)) = (dx, dy) else { return Vec3::ZERO };
            let n = dx.cross(dy).normalize_or_zero();
            // Facing the camera (which sits at the origin of camera space).
            let n = if n.dot(c) > 0.0 { -n } else { n };
            cam.rotation.inverse() * n
        })
        .collect()
}

/// The Φ_sem (`[embedding dim][labels]` row-major weight and zero bias) that maps the
/// semantic code e_j to `embeddings[j]`: its column j is that embedding.
pub fn label_projection<E: AsRef<[f32]>>(embeddings: &[E]) -> (Vec<f32>, Vec<f32>) {
    let dim = embeddings.first().map_or(0, |e| e.as_ref().len());
    let n = embeddings.len();
    let weight = (0..dim * n).map(|i| embeddings[i % n].as_ref()[i / n]).collect();
    (weight, vec![0.0; dim])
}
