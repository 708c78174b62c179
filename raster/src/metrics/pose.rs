//! Camera errors after similarity alignment. Predicted cameras live in the network's frame
//! (view 0's camera, unknown scale); the Umeyama similarity x_gt = s·R·x_pred + t that best
//! maps the predicted camera centres onto the ground-truth ones (least squares) aligns them
//! first. With fewer than three cameras, or collinear centres, the centres do not fix the
//! rotation: then R aligns view 0's orientation, s matches the spread of the centres and t
//! puts view 0's centre on its ground truth. Errors: the angle between each aligned
//! predicted camera orientation and the true one (degrees), and the distance between aligned
//! and true centres (ground-truth units). [`Similarity::map_camera`] moves a camera between
//! the two frames, for rendering ground-truth target views in the predicted frame.

use glam::{DMat3, DQuat, DVec3};
use inssplat_proto::Camera;
use nalgebra::{Matrix3, SVD, Vector3};

use super::{MetricError, same_len};

/// x ↦ scale · rotation · x + translation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    pub scale: f64,
    pub rotation: DMat3,
    pub translation: DVec3,
}

impl Similarity {
    pub fn apply(&self, x: DVec3) -> DVec3 {
        self.scale * (self.rotation * x) + self.translation
    }

    pub fn inverse(&self) -> Self {
        let rt = self.rotation.transpose();
        Self { scale: 1.0 / self.scale, rotation: rt, translation: -(rt * self.translation) / self.scale }
    }

    /// The same physical camera expressed in the target frame: it sees the mapped scene as
    /// the original saw the original (camera coordinates scale by `scale`, which leaves the
    /// projection unchanged).
    pub fn map_camera(&self, cam: &Camera) -> Camera {
        let r_cam = DMat3::from_quat(cam.rotation.as_dquat());
        let rotation = r_cam * self.rotation.transpose();
        let translation = self.scale * cam.translation.as_dvec3() - rotation * self.translation;
        Camera {
            intrinsics: cam.intrinsics,
            rotation: DQuat::from_mat3(&rotation).normalize().as_quat(),
            translation: translation.as_vec3(),
        }
    }
}

/// Least-squares similarity mapping `src` onto `dst` (Umeyama 1991); `None` when the points
/// do not fix it (fewer than 3, or all collinear).
pub fn umeyama(src: &[DVec3], dst: &[DVec3]) -> Result<Option<Similarity>, MetricError> {
    same_len("point sets", src.len(), dst.len())?;
    let n = src.len();
    if n < 3 {
        return Ok(None);
    }
    let mean = |v: &[DVec3]| v.iter().copied().sum::<DVec3>() / n as f64;
    let (ms, md) = (mean(src), mean(dst));
    let mut cov = Matrix3::<f64>::zeros();
    let mut var_src = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let (s, d) = (*s - ms, *d - md);
        cov += Vector3::new(d.x, d.y, d.z) * Vector3::new(s.x, s.y, s.z).transpose();
        var_src += s.length_squared();
    }
    cov /= n as f64;
    var_src /= n as f64;
    let svd = SVD::new(cov, true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else { return Ok(None) };
    let d = svd.singular_values;
    if var_src <= 0.0 || d[1] <= 1e-9 * d[0].max(f64::MIN_POSITIVE) {
        return Ok(None);
    }
    let mut sign = Matrix3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        sign[(2, 2)] = -1.0;
    }
    let r = u * sign * v_t;
    let scale = (d[0] + d[1] + sign[(2, 2)] * d[2]) / var_src;
    let rotation = DMat3::from_cols_array(&[
        r[(0, 0)],
        r[(1, 0)],
        r[(2, 0)],
        r[(0, 1)],
        r[(1, 1)],
        r[(2, 1)],
        r[(0, 2)],
        r[(1, 2)],
        r[(2, 2)],
    ]);
    Ok(Some(Similarity { scale, rotation, translation: md - scale * (rotation * ms) }))
}

#[derive(Debug, Clone, PartialEq)]
pub struct PoseScores {
    /// Mean and per-camera angle between aligned predicted and true orientations, degrees.
    pub rotation_deg: f64,
    pub rotation_deg_per_camera: Vec<f64>,
    /// Mean and per-camera distance between aligned predicted and true centres.
    pub translation: f64,
    pub translation_per_camera: Vec<f64>,
    /// predicted frame → ground-truth frame.
    pub alignment: Similarity,
    /// Whether Umeyama on the centres decided the alignment (else view 0 did, see above).
    pub umeyama: bool,
}

/// Camera errors of `pred` against `gt` (same order, view 0 first); `None` for no camera.
pub fn camera_errors(pred: &[Camera], gt: &[Camera]) -> Result<Option<PoseScores>, MetricError> {
    same_len("camera lists", pred.len(), gt.len())?;
    if pred.is_empty() {
        return Ok(None);
    }
    let centres = |c: &[Camera]| c.iter().map(|c| c.center().as_dvec3()).collect::<Vec<_>>();
    let (cp, cg) = (centres(pred), centres(gt));
    let c2w = |c: &Camera| DMat3::from_quat(c.rotation.inverse().as_dquat());
    let (alignment, by_umeyama) = match umeyama(&cp, &cg)? {
        Some(s) => (s, true),
        None => {
            let rotation = c2w(&gt[0]) * c2w(&pred[0]).transpose();
            let spread = |c: &[DVec3]| c.iter().map(|x| (*x - c[0]).length()).sum::<f64>();
            let scale = if spread(&cp) > 0.0 { spread(&cg) / spread(&cp) } else { 1.0 };
            (Similarity { scale, rotation, translation: cg[0] - scale * (rotation * cp[0]) }, false)
        }
    };
    let rot: Vec<f64> = pred
        .iter()
        .zip(gt)
        .map(|(p, g)| {
            // Angle of the relative rotation, 2·atan2(|v|, |w|) of its quaternion: well
            // conditioned near zero, unlike acos of the trace.
            let rel = DQuat::from_mat3(&(c2w(g).transpose() * alignment.rotation * c2w(p)));
            (2.0 * rel.xyz().length().atan2(rel.w.abs())).to_degrees()
        })
        .collect();
    let trans: Vec<f64> = cp.iter().zip(&cg).map(|(p, g)| (alignment.apply(*p) - *g).length()).collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    Ok(Some(PoseScores {
        rotation_deg: mean(&rot),
        translation: mean(&trans),
        rotation_deg_per_camera: rot,
        translation_per_camera: trans,
        alignment,
        umeyama: by_umeyama,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;
    use inssplat_proto::Intrinsics;

    fn ring(n: usize, radius: f32, height: f32) -> Vec<Camera> {
        let k = Intrinsics::from_fov_y(64, 64, 1.0);
        (0..n)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / n as f32;
                let eye = glam::Vec3::new(radius * a.cos(), height + 0.1 * i as f32, radius * a.sin());
                Camera::look_at(k, eye, glam::Vec3::ZERO, glam::Vec3::Y)
            })
            .collect()
    }

    fn sim() -> Similarity {
        Similarity {
            scale: 0.4,
            rotation: DMat3::from_euler(glam::EulerRot::YXZ, 0.7, -0.2, 0.4),
            translation: DVec3::new(1.0, -2.0, 0.5),
        }
    }

    #[test]
    fn umeyama_recovers_a_known_similarity() {
        let src: Vec<DVec3> = (0..6).map(|i| DVec3::new(i as f64, (i * i) as f64 * 0.3, (i % 3) as f64)).collect();
        let dst: Vec<DVec3> = src.iter().map(|&x| sim().apply(x)).collect();
        let s = umeyama(&src, &dst).unwrap().unwrap();
        assert!((s.scale - 0.4).abs() < 1e-9);
        assert!(s.rotation.abs_diff_eq(sim().rotation, 1e-9) && s.translation.abs_diff_eq(sim().translation, 1e-9));
        let line: Vec<DVec3> = (0..4).map(|i| DVec3::X * i as f64).collect();
        assert_eq!(umeyama(&line, &line).unwrap(), None);
    }

    #[test]
    fn cameras_moved_by_a_similarity_have_zero_error_and_perturbations_are_measured() {
        let gt = ring(5, 3.0, 1.5);
        // The predicted frame is the ground truth one mapped by the inverse similarity.
        let to_pred = sim().inverse();
        let mut pred: Vec<Camera> = gt.iter().map(|c| to_pred.map_camera(c)).collect();
        let p = camera_errors(&pred, &gt).unwrap().unwrap();
        assert!(p.umeyama && p.rotation_deg < 1e-3 && p.translation < 1e-4, "{p:?}");
        assert!((p.alignment.scale - 0.4).abs() < 1e-5);
        // Mapped cameras project a mapped point to the same pixel.
        let x = glam::Vec3::new(0.3, 0.2, -0.4);
        let xp = to_pred.apply(x.as_dvec3()).as_vec3();
        let (u0, v0) = gt[2].project(gt[2].world_to_camera(x));
        let (u1, v1) = pred[2].project(pred[2].world_to_camera(xp));
        assert!((u0 - u1).abs() < 1e-3 && (v0 - v1).abs() < 1e-3);
        // Turning one predicted camera by 10° about its optical axis (centre kept): that camera
        // errs by 10°, the others not at all.
        let centre = pred[3].center();
        pred[3].rotation = (Quat::from_rotation_z(10f32.to_radians()) * pred[3].rotation).normalize();
        pred[3].translation = -(pred[3].rotation * centre);
        let p = camera_errors(&pred, &gt).unwrap().unwrap();
        assert!((p.rotation_deg_per_camera[3] - 10.0).abs() < 1e-2, "{p:?}");
        assert!((p.rotation_deg - 2.0).abs() < 1e-2);
    }

    #[test]
    fn two_cameras_align_on_view_zero() {
        let gt = ring(2, 2.0, 1.0);
        let pred: Vec<Camera> = gt.iter().map(|c| sim().map_camera(c)).collect();
        let p = camera_errors(&pred, &gt).unwrap().unwrap();
        assert!(!p.umeyama && p.rotation_deg < 1e-3 && p.translation < 1e-4, "{p:?}");
        assert!((p.alignment.scale - 2.5).abs() < 1e-5);
    }
}
