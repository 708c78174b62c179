//! Pinhole cameras in the one convention every inssplat crate uses inside: OpenCV axes
//! (+x right, +y down, +z forward), a world-to-camera rigid transform, intrinsics in pixels
//! with pixel centres at +0.5. The dataset format stores nerfstudio/OpenGL camera-to-world
//! matrices; [`Camera::from_nerfstudio`] and [`Camera::to_nerfstudio`] are the only place the
//! two conventions meet.

use glam::{DMat4, Mat3, Quat, Vec3};
use serde::{Deserialize, Serialize};

/// Pinhole intrinsics in pixels for an image of `width` × `height`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// Intrinsics with the principal point at the image centre and the given vertical
    /// field of view (radians), square pixels.
    pub fn from_fov_y(width: u32, height: u32, fov_y: f32) -> Self {
        let f = 0.5 * height as f32 / (0.5 * fov_y).tan();
        Self { fx: f, fy: f, cx: 0.5 * width as f32, cy: 0.5 * height as f32, width, height }
    }

    /// Vertical and horizontal field of view in radians.
    pub fn fov(&self) -> (f32, f32) {
        (
            2.0 * (0.5 * self.height as f32 / self.fy).atan(),
            2.0 * (0.5 * self.width as f32 / self.fx).atan(),
        )
    }

    /// The same camera at another image size (intrinsics scale with the image).
    pub fn scaled_to(&self, width: u32, height: u32) -> Self {
        let sx = width as f32 / self.width as f32;
        let sy = height as f32 / self.height as f32;
        Self {
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            width,
            height,
        }
    }
}

/// A camera: intrinsics plus the rigid world-to-camera transform `x_cam = R x_world + t`
/// (OpenCV axes).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub intrinsics: Intrinsics,
    /// Rotation world → camera, unit quaternion.
    pub rotation: Quat,
    /// Translation world → camera.
    pub translation: Vec3,
}

/// Why a camera-to-world matrix cannot be a camera.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    #[error("matrix has a non-finite entry at row {row}, column {col}")]
    NonFinite { row: usize, col: usize },
    #[error("bottom row is {0:?}, expected [0, 0, 0, 1]")]
    NotAffine([f64; 4]),
    #[error("rotation part is singular (determinant {0:.3e})")]
    Singular(f64),
}

/// OpenGL camera axes (x right, y up, looking down −z) to OpenCV camera axes: flip y and z.
const GL_FROM_CV: DMat4 = DMat4::from_cols_array(&[
    1.0, 0.0, 0.0, 0.0, //
    0.0, -1.0, 0.0, 0.0, //
    0.0, 0.0, -1.0, 0.0, //
    0.0, 0.0, 0.0, 1.0,
]);

impl Camera {
    /// A camera looking from `eye` at `target` with the given world up direction (OpenCV
    /// axes inside: the image's −y points along `up`).
    pub fn look_at(intrinsics: Intrinsics, eye: Vec3, target: Vec3, up: Vec3) -> Self {
        let forward = (target - eye).normalize();
        let right = forward.cross(up).normalize();
        let down = forward.cross(right);
        // Rows of the world→camera rotation are the camera axes in world coordinates.
        let r = Mat3::from_cols(right, down, forward).transpose();
        let rotation = Quat::from_mat3(&r).normalize();
        Self { intrinsics, rotation, translation: -(rotation * eye) }
    }

    /// Camera centre in world coordinates.
    pub fn center(&self) -> Vec3 {
        -(self.rotation.inverse() * self.translation)
    }

    /// World point → camera coordinates.
    pub fn world_to_camera(&self, p: Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }

    /// Camera coordinates → world point.
    pub fn camera_to_world(&self, p: Vec3) -> Vec3 {
        self.rotation.inverse() * (p - self.translation)
    }

    /// Pixel coordinates (pixel centres at +0.5) and depth of a camera-space point.
    pub fn project(&self, p_cam: Vec3) -> (f32, f32) {
        let k = &self.intrinsics;
        (k.fx * p_cam.x / p_cam.z + k.cx, k.fy * p_cam.y / p_cam.z + k.cy)
    }

    /// The pixel (column, row) of the image that a camera-space point in front of the camera
    /// falls in; `None` behind the camera or outside the image.
    pub fn pixel_of(&self, p_cam: Vec3) -> Option<(usize, usize)> {
        if p_cam.z <= 0.0 {
            return None;
        }
        let (u, v) = self.project(p_cam);
        let (w, h) = (self.intrinsics.width as f32, self.intrinsics.height as f32);
        ((0.0..w).contains(&u) && (0.0..h).contains(&v)).then_some((u as usize, v as usize))
    }

    /// Camera-space point at depth `z` (along +z) through pixel position (`u`, `v`).
    pub fn unproject(&self, u: f32, v: f32, z: f32) -> Vec3 {
        let k = &self.intrinsics;
        Vec3::new((u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z)
    }

    /// 4×4 world-to-camera matrix (column-major, OpenCV axes).
    pub fn view_matrix(&self) -> glam::Mat4 {
        glam::Mat4::from_rotation_translation(self.rotation, self.translation)
    }

    /// From a nerfstudio / OpenGL / Blender camera-to-world matrix given row-major, as stored
    /// in `transforms.json`. Rejects non-finite, non-affine and singular matrices. A matrix
    /// whose rotation part carries scale is orthonormalized (its scale is not a camera
    /// property).
    pub fn from_nerfstudio(
        intrinsics: Intrinsics,
        c2w_rows: &[[f64; 4]; 4],
    ) -> Result<Self, CameraError> {
        for (row, r) in c2w_rows.iter().enumerate() {
            for (col, v) in r.iter().enumerate() {
                if !v.is_finite() {
                    return Err(CameraError::NonFinite { row, col });
                }
            }
        }
        let bottom = c2w_rows[3];
        if bottom.iter().zip([0.0, 0.0, 0.0, 1.0]).any(|(a, b)| (a - b).abs() > 1e-6) {
            return Err(CameraError::NotAffine(bottom));
        }
        let gl_c2w = DMat4::from_cols_array_2d(c2w_rows).transpose();
        let det = glam::DMat3::from_mat4(gl_c2w).determinant();
        if det.abs() < 1e-9 {
            return Err(CameraError::Singular(det));
        }
        let cv_c2w = gl_c2w * GL_FROM_CV;
        let (_scale, rot_c2w, center) = cv_c2w.to_scale_rotation_translation();
        let rotation = rot_c2w.inverse().as_quat().normalize();
        let translation = -(rotation * center.as_vec3());
        Ok(Self { intrinsics, rotation, translation })
    }

    /// To a nerfstudio / OpenGL camera-to-world matrix, row-major as stored in
    /// `transforms.json`.
    pub fn to_nerfstudio(&self) -> [[f64; 4]; 4] {
        let cv_c2w = DMat4::from_rotation_translation(
            self.rotation.inverse().as_dquat(),
            self.center().as_dvec3(),
        );
        (cv_c2w * GL_FROM_CV.inverse()).transpose().to_cols_array_2d()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn k() -> Intrinsics {
        Intrinsics::from_fov_y(128, 96, 1.0)
    }

    #[test]
    fn nerfstudio_round_trip_is_exact_to_float_precision() {
        let cam =
            Camera::look_at(k(), Vec3::new(1.0, 1.5, -2.0), Vec3::new(0.2, 0.5, 0.3), Vec3::Y);
        let back = Camera::from_nerfstudio(k(), &cam.to_nerfstudio()).unwrap();
        assert!(back.rotation.dot(cam.rotation).abs() > 1.0 - 1e-6, "{back:?} vs {cam:?}");
        assert!((back.translation - cam.translation).length() < 1e-5);
    }

    #[test]
    fn opengl_identity_looks_down_negative_z_with_y_up() {
        let id = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let cam = Camera::from_nerfstudio(k(), &id).unwrap();
        // A point in front of an OpenGL camera is at world −z; above it is world +y.
        let p = cam.world_to_camera(Vec3::new(0.0, 1.0, -5.0));
        assert!(p.z > 0.0, "in front means +z in OpenCV: {p}");
        assert!(p.y < 0.0, "up means −y in OpenCV: {p}");
        let (u, v) = cam.project(p);
        assert!((u - 64.0).abs() < 1e-4 && v < 48.0);
    }

    #[test]
    fn pixel_of_finds_the_pixel_a_point_falls_in_and_nothing_outside() {
        let cam =
            Camera::look_at(k(), Vec3::new(-1.0, 2.0, 0.5), Vec3::new(0.3, -0.2, 4.0), Vec3::Y);
        let (w, h) = (cam.intrinsics.width as f32, cam.intrinsics.height as f32);
        for (u, v) in [(0.25, 0.75), (70.5, 30.2), (w - 0.01, h - 0.01)] {
            let p = cam.unproject(u, v, 2.5);
            assert_eq!(
                cam.pixel_of(p),
                Some((u.floor() as usize, v.floor() as usize)),
                "({u}, {v})"
            );
        }
        for (u, v) in [(-0.01, 10.0), (10.0, -0.01), (w, 10.0), (10.0, h)] {
            assert_eq!(cam.pixel_of(cam.unproject(u, v, 2.5)), None, "({u}, {v}) is outside");
        }
        assert_eq!(cam.pixel_of(-cam.unproject(30.0, 30.0, 2.5)), None, "behind the camera");
    }

    #[test]
    fn look_at_puts_target_on_the_optical_axis() {
        let target = Vec3::new(0.3, -0.2, 4.0);
        let cam = Camera::look_at(k(), Vec3::new(-1.0, 2.0, 0.5), target, Vec3::Y);
        let p = cam.world_to_camera(target);
        assert!(p.x.abs() < 1e-5 && p.y.abs() < 1e-5 && p.z > 0.0, "{p}");
        let up = cam.world_to_camera(target + Vec3::Y) - p;
        assert!(up.y < 0.0, "world up appears upwards in the image");
        let back = cam.camera_to_world(cam.unproject(70.0, 30.0, 2.0));
        let again = cam.world_to_camera(back);
        let (u, v) = cam.project(again);
        assert!((u - 70.0).abs() < 1e-3 && (v - 30.0).abs() < 1e-3);
    }

    #[test]
    fn rejects_bad_matrices() {
        let mut m = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        m[1][2] = f64::NAN;
        assert_eq!(
            Camera::from_nerfstudio(k(), &m).unwrap_err(),
            CameraError::NonFinite { row: 1, col: 2 }
        );
        let singular = [
            [1.0, 0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        assert!(matches!(Camera::from_nerfstudio(k(), &singular), Err(CameraError::Singular(_))));
        let projective = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0, 1.0],
        ];
        assert!(matches!(
            Camera::from_nerfstudio(k(), &projective),
            Err(CameraError::NotAffine(_))
        ));
    }

    #[test]
    fn fov_round_trip() {
        let k = Intrinsics::from_fov_y(100, 100, 0.9);
        assert!((k.fov().0 - 0.9).abs() < 1e-6);
        let s = k.scaled_to(200, 50);
        assert_eq!((s.cx, s.cy), (100.0, 25.0));
    }
}
