//! The rotation closest to a 3×3 matrix (Frobenius norm): R = U·diag(1, 1, det(U·Vᵀ))·Vᵀ from
//! its SVD. Fits a rotation to a sum of outer products (Kabsch) or averages rotations (the
//! chordal mean of a sum of rotation matrices).

use glam::DMat3;
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
