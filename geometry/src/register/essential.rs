//! The relative pose of two views from their matches' viewing rays alone (no depth): the
//! essential matrix of eight matches (the normalised eight-point algorithm), RANSAC on the
//! Sampson distance, decomposed into the rotation and the direction of the translation that
//! put the matches in front of both cameras. Its scale comes from the predicted depth.

use glam::{DMat3, DVec3};
use nalgebra::{Matrix3, SMatrix, SymmetricEigen};
use rand::Rng;
use rand::seq::index::sample;

use super::relative::{Correspondence, Model};

/// A match's viewing ray in camera i and in camera j, at unit depth.
fn rays(c: &Correspondence) -> (DVec3, DVec3) {
    let n = |p: glam::Vec3| (p / p.z).as_dvec3();
    (n(c.point_i), n(c.point_j))
}

/// The essential matrix of the matches `pick` (x_jᵀ E x_i = 0), projected onto the essential
/// manifold.
fn eight_point(corr: &[Correspondence], pick: impl Iterator<Item = usize>) -> Option<Matrix3<f64>> {
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for k in pick {
        let (a, b) = rays(&corr[k]);
        let row = SMatrix::<f64, 1, 9>::from_row_slice(&[
            b.x * a.x,
            b.x * a.y,
            b.x,
            b.y * a.x,
            b.y * a.y,
            b.y,
            a.x,
            a.y,
            1.0,
        ]);
        ata += row.transpose() * row;
    }
    let eig = SymmetricEigen::new(ata);
    let k = eig.eigenvalues.imin();
    let e = eig.eigenvectors.column(k);
    let m = Matrix3::new(e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7], e[8]);
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    Some(u * Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, 0.0)) * vt)
}

/// Sampson distance² of `c` under `e`, in units of the rays (× focal² for pixels²).
fn sampson2(e: &Matrix3<f64>, c: &Correspondence) -> f64 {
    let (a, b) = rays(c);
    let (a, b) = (nalgebra::Vector3::new(a.x, a.y, a.z), nalgebra::Vector3::new(b.x, b.y, b.z));
    let (ea, etb) = (e * a, e.transpose() * b);
    let r = b.dot(&ea);
    let den = ea.x * ea.x + ea.y * ea.y + etb.x * etb.x + etb.y * etb.y;
    if den > 0.0 { r * r / den } else { f64::INFINITY }
}

/// Depths (in camera i, in camera j) of `c` under the motion (r, t): x_j = r·x_i + t.
fn depths(r: DMat3, t: DVec3, c: &Correspondence) -> (f64, f64) {
    let (a, b) = rays(c);
    // z_j b − z_i r a = t, least squares in (z_i, z_j).
    let ra = r * a;
    let (p, q) = (-ra, b);
    let (pp, pq, qq) = (p.dot(p), p.dot(q), q.dot(q));
    let (pt, qt) = (p.dot(t), q.dot(t));
    let det = pp * qq - pq * pq;
    if det.abs() < 1e-12 {
        return (0.0, 0.0);
    }
    ((qq * pt - pq * qt) / det, (pp * qt - pq * pt) / det)
}

/// The rotation and unit translation of `e` that puts most of the matches `of` in front of both
/// cameras.
fn decompose(e: &Matrix3<f64>, corr: &[Correspondence], of: &[usize]) -> Option<(DMat3, DVec3)> {
    let svd = e.svd(true, true);
    let (mut u, mut vt) = (svd.u?, svd.v_t?);
    if u.determinant() < 0.0 {
        u = -u;
    }
    if vt.determinant() < 0.0 {
        vt = -vt;
    }
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    // nalgebra stores column-major, as glam's column arrays are.
    let to_glam = |m: Matrix3<f64>| DMat3::from_cols_slice(m.as_slice());
    let t = DVec3::new(u[(0, 2)], u[(1, 2)], u[(2, 2)]);
    [u * w * vt, u * w.transpose() * vt]
        .into_iter()
        .flat_map(|r| [(to_glam(r), t), (to_glam(r), -t)])
        .max_by_key(|&(r, t)| {
            of.iter()
                .filter(|&&k| {
                    let (zi, zj) = depths(r, t, &corr[k]);
                    zi > 0.0 && zj > 0.0
                })
                .count()
        })
}

/// The best essential-matrix pose of `corr` within `tau` pixels (Sampson) at focal length
/// `focal` (pixels), scaled by the predicted depth (the median ratio of the inliers' lifted
/// depth to their depth at unit baseline); with its inliers' indices.
pub(super) fn essential_pose(
    corr: &[Correspondence],
    focal: f64,
    tau: f64,
    iterations: usize,
    rng: &mut impl Rng,
) -> Option<(Model, Vec<usize>)> {
    if corr.len() < 8 {
        return None;
    }
    let tau2 = (tau / focal).powi(2);
    let mut best: Option<(f64, Matrix3<f64>)> = None;
    for _ in 0..iterations {
        let Some(e) = eight_point(corr, sample(rng, corr.len(), 8).into_iter()) else { continue };
        let cost: f64 = corr.iter().map(|c| sampson2(&e, c).min(tau2)).sum();
        if best.is_none_or(|(b, _)| cost < b) {
            best = Some((cost, e));
        }
    }
    let inliers_of = |e: &Matrix3<f64>| -> Vec<usize> {
        (0..corr.len()).filter(|&k| sampson2(e, &corr[k]) < tau2).collect()
    };
    let (_, e) = best?;
    // Once more on all the inliers.
    let e = eight_point(corr, inliers_of(&e).into_iter())?;
    let inliers = inliers_of(&e);
    let (r, t) = decompose(&e, corr, &inliers)?;
    let mut ratios: Vec<f64> = inliers
        .iter()
        .filter_map(|&k| {
            let (zi, _) = depths(r, t, &corr[k]);
            (zi > 1e-9).then(|| corr[k].point_i.z as f64 / zi)
        })
        .collect();
    ratios.sort_by(f64::total_cmp);
    let scale = *ratios.get(ratios.len() / 2)?;
    Some((Model { r, t: t * scale }, inliers))
}

/// How many of `corr` lie within `tau` pixels (Sampson) of the epipolar geometry of `m`.
pub(super) fn epipolar_inliers(m: &Model, corr: &[Correspondence], focal: f64, tau: f64) -> usize {
    let t = m.t;
    if t.length() < 1e-9 {
        return 0;
    }
    let t = nalgebra::Vector3::new(t.x, t.y, t.z) / t.length();
    let e = t.cross_matrix() * Matrix3::from_column_slice(&m.r.to_cols_array());
    let tau2 = (tau / focal).powi(2);
    corr.iter().filter(|c| sampson2(&e, c) < tau2).count()
}
