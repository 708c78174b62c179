//! The rotation closest to a 3×3 matrix (Frobenius norm): R = U·diag(1, 1, det(U·Vᵀ))·Vᵀ from
//! its SVD. Fits a rotation to a sum of outer products (Kabsch) or averages rotations (the
//! chordal mean of a sum of rotation matrices), and the angle of a rotation.

use glam::{DMat3, DQuat};
use inssplat_proto::Camera;
use nalgebra::{Matrix3, SVD};

/// The rotation nearest to `m`; `None` when the SVD does not converge.
pub fn nearest_rotation(m: DMat3) -> Option<DMat3> {
    let svd = SVD::new(Matrix3::from_column_slice(&m.to_cols_array()), true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut sign = Matrix3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        sign[(2, 2)] = -1.0;
    }
    Some(DMat3::from_cols_slice((u * sign * v_t).as_slice()))
}

/// Angle of a rotation in degrees, 2·atan2(|v|, |w|) of its quaternion: well conditioned near
/// zero, unlike acos of the trace.
pub fn angle_deg(rotation: DMat3) -> f64 {
    let q = DQuat::from_mat3(&rotation);
    (2.0 * q.xyz().length().atan2(q.w.abs())).to_degrees()
}

/// Angle in degrees between the orientations of two cameras ([`angle_deg`] of the rotation
/// that takes one to the other).
pub fn turn_deg(a: &Camera, b: &Camera) -> f64 {
    angle_deg(DMat3::from_quat((a.rotation * b.rotation.inverse()).as_dquat()))
}
