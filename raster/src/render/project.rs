//! Projection of 3D Gaussians to screen-space ellipses (EWA splatting) and its hand-written
//! vector–Jacobian product. One Gaussian at a time, no state: the forward gives the 2D mean,
//! the conic (inverse 2D covariance, dilated by [`LOW_PASS`] pixels), the opacity, the camera
//! depth and the pixel extent that bounds where its alpha can reach the cutoff; the backward
//! maps gradients on those back to the world-space parameters.
//!
//! Conventions: OpenCV camera axes, `x_cam = W x_world + t`, pixel centres at +0.5 (so the
//! continuous pixel coordinate of a camera point is `fx x/z + cx`). Like gsplat, the Jacobian
//! is evaluated at the camera point with x/z and y/z clamped to 1.3 × the half field of view,
//! which keeps Gaussians far outside the frustum from producing enormous footprints.

use glam::{Mat2, Mat3, Vec2, Vec3};
use inssplat_proto::Camera;

use super::{LOW_PASS, NEAR_PLANE};

/// Everything about a camera that projection needs, precomputed once per render.
#[derive(Debug, Clone, Copy)]
pub(crate) struct View {
    /// World → camera rotation.
    pub rot: Mat3,
    pub trans: Vec3,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// Clamp bounds of x/z (negative side as a positive number, positive side) and y/z.
    pub lim_x: (f32, f32),
    pub lim_y: (f32, f32),
}

impl View {
    pub fn new(camera: &Camera) -> Self {
        let k = &camera.intrinsics;
        let (w, h) = (k.width as f32, k.height as f32);
        let tan_x = 0.5 * w / k.fx;
        let tan_y = 0.5 * h / k.fy;
        Self {
            rot: Mat3::from_quat(camera.rotation.normalize()),
            trans: camera.translation,
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            lim_x: (k.cx / k.fx + 0.3 * tan_x, (w - k.cx) / k.fx + 0.3 * tan_x),
            lim_y: (k.cy / k.fy + 0.3 * tan_y, (h - k.cy) / k.fy + 0.3 * tan_y),
        }
    }
}

/// A Gaussian as the compositor sees it.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Projected {
    /// Continuous pixel coordinates of the centre.
    pub xy: [f32; 2],
    /// Inverse 2D covariance (a, b, c) of `[[a, b], [b, c]]`.
    pub conic: [f32; 3],
    pub opacity: f32,
    /// Camera-space z of the centre (what expected depth averages).
    pub depth: f32,
    /// Half extents in pixels of the box outside which alpha is below the cutoff floor.
    pub extent: [f32; 2],
    /// The same bound as an ellipse: alpha can reach the floor only where
    /// dᵀ·conic·d ≤ `k2` (with a small margin against rounding).
    pub k2: f32,
}

/// Gradients of the loss w.r.t. one Gaussian's projected quantities.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ProjectedGrad {
    pub xy: [f32; 2],
    /// W.r.t. the scalars (a, b, c) of the conic, b counted once (power = −½(a dx² + 2b dx dy + c
    /// dy²)).
    pub conic: [f32; 3],
    pub opacity: f32,
    pub depth: f32,
}

impl ProjectedGrad {
    /// Whether every gradient is exactly zero (the Gaussian reached no pixel).
    pub fn is_zero(&self) -> bool {
        self.xy.iter().chain(&self.conic).chain([&self.opacity, &self.depth]).all(|&g| g == 0.0)
    }
}

/// Gradients w.r.t. one Gaussian's parameters, and its share of the camera's.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ParamGrad {
    pub mean: [f32; 3],
    pub log_scale: [f32; 3],
    pub rotation: [f32; 4],
    pub logit_opacity: f32,
    /// dL/dW of the world → camera rotation matrix, column-major.
    pub view_rot: [f32; 9],
    pub view_trans: [f32; 3],
}

/// Quantities shared by the forward and the backward of one projection.
struct Geometry {
    p_cam: Vec3,
    /// Camera point with x and y clamped to the Jacobian's field of view.
    t_clamped: Vec3,
    clamped: [bool; 2],
    /// Normalized quaternion (w, x, y, z) and the norm of the input.
    q: [f32; 4],
    q_norm: f32,
    r: Mat3,
    scale: Vec3,
    /// M = R diag(scale), Σ_world = M Mᵀ.
    m: Mat3,
    /// Σ in camera axes.
    v: Mat3,
    /// Rows of the 2×3 projection Jacobian.
    j: [Vec3; 2],
    cov2d: Mat2,
}

/// Rotation matrix of a unit quaternion (w, x, y, z).
fn rotation_matrix([w, x, y, z]: [f32; 4]) -> Mat3 {
    Mat3::from_cols(
        Vec3::new(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        Vec3::new(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        Vec3::new(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    )
}

/// Smallest quaternion norm accepted; below it the rotation is undefined and the Gaussian
/// is skipped (this covers zero and denormal quaternions).
const MIN_QUAT_NORM: f32 = 1e-12;

fn geometry(
    view: &View,
    mean: [f32; 3],
    log_scale: [f32; 3],
    rotation: [f32; 4],
) -> Option<Geometry> {
    let p_cam = view.rot * Vec3::from(mean) + view.trans;
    if p_cam.z.is_nan() || p_cam.z < NEAR_PLANE {
        return None;
    }
    let q_norm = rotation.iter().map(|c| c * c).sum::<f32>().sqrt();
    if !q_norm.is_finite() || q_norm < MIN_QUAT_NORM {
        return None;
    }
    let q = rotation.map(|c| c / q_norm);
    let r = rotation_matrix(q);
    let scale = Vec3::from(log_scale.map(f32::exp));
    let m = Mat3::from_cols(r.x_axis * scale.x, r.y_axis * scale.y, r.z_axis * scale.z);
    let sigma = m * m.transpose();
    let v = view.rot * sigma * view.rot.transpose();

    let z = p_cam.z;
    let (rx, ry) = (p_cam.x / z, p_cam.y / z);
    let cx = rx.clamp(-view.lim_x.0, view.lim_x.1);
    let cy = ry.clamp(-view.lim_y.0, view.lim_y.1);
    let t_clamped = Vec3::new(cx * z, cy * z, z);
    let clamped = [cx != rx, cy != ry];
    let j = [
        Vec3::new(view.fx / z, 0.0, -view.fx * t_clamped.x / (z * z)),
        Vec3::new(0.0, view.fy / z, -view.fy * t_clamped.y / (z * z)),
    ];
    let vj0 = v * j[0];
    let vj1 = v * j[1];
    let b = j[0].dot(vj1);
    let cov2d = Mat2::from_cols(
        Vec2::new(j[0].dot(vj0) + LOW_PASS, b),
        Vec2::new(b, j[1].dot(vj1) + LOW_PASS),
    );
    Some(Geometry { p_cam, t_clamped, clamped, q, q_norm, r, scale, m, v, j, cov2d })
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// Projects one Gaussian. `None` when it cannot be seen: centre nearer than [`NEAR_PLANE`],
/// degenerate quaternion or covariance, non-finite input or result, or an opacity below
/// `alpha_floor` (the smallest alpha the compositor keeps).
pub(crate) fn project(
    view: &View,
    mean: [f32; 3],
    log_scale: [f32; 3],
    rotation: [f32; 4],
    logit_opacity: f32,
    alpha_floor: f32,
) -> Option<Projected> {
    let finite = mean.iter().chain(&log_scale).chain(&rotation).all(|v| v.is_finite());
    if !finite || !logit_opacity.is_finite() {
        return None;
    }
    let opacity = sigmoid(logit_opacity);
    if opacity < alpha_floor {
        return None;
    }
    let g = geometry(view, mean, log_scale, rotation)?;
    let (a, b, c) = (g.cov2d.x_axis.x, g.cov2d.x_axis.y, g.cov2d.y_axis.y);
    let det = a * c - b * b;
    if !det.is_finite() || det <= 0.0 {
        return None;
    }
    let conic = [c / det, -b / det, a / det];
    let z = g.p_cam.z;
    let xy = [view.fx * g.p_cam.x / z + view.cx, view.fy * g.p_cam.y / z + view.cy];
    // o·exp(−½ m) ≥ floor  ⇔  m ≤ 2 ln(o / floor); the ellipse dᵀΣ⁻¹d ≤ k² has the
    // axis-aligned half extents k·√Σxx, k·√Σyy.
    // The 1e-3 margin keeps pixels whose f32 value rounds to just above the floor inside.
    let k2 = 2.0 * (opacity / alpha_floor).ln() + 1e-3;
    let extent = [(k2 * a).sqrt(), (k2 * c).sqrt()];
    let all_finite = conic.iter().chain(&xy).chain(&extent).all(|v| v.is_finite());
    all_finite.then_some(Projected { xy, conic, opacity, depth: z, extent, k2 })
}

/// Gradient w.r.t. a quaternion (w, x, y, z) of norm `norm`, normalized to `unit` before
/// use, of a loss whose gradient w.r.t. the rotation matrix is `g_r`.
pub(crate) fn quaternion_vjp(unit: [f32; 4], norm: f32, g_r: Mat3) -> [f32; 4] {
    let g_unit = rotation_vjp(unit, g_r);
    let dot: f32 = g_unit.iter().zip(&unit).map(|(a, b)| a * b).sum();
    [0, 1, 2, 3].map(|i| (g_unit[i] - unit[i] * dot) / norm)
}

/// d R / d q for each component of a unit quaternion, contracted with `g_r`.
fn rotation_vjp([w, x, y, z]: [f32; 4], g_r: Mat3) -> [f32; 4] {
    // Element (row, col) of a matrix given as rows.
    let at = |row: usize, col: usize| g_r.col(col)[row];
    let contract = |d: [[f32; 3]; 3]| -> f32 {
        (0..3).map(|r| (0..3).map(|c| d[r][c] * at(r, c)).sum::<f32>()).sum()
    };
    [
        contract([[0.0, -2.0 * z, 2.0 * y], [2.0 * z, 0.0, -2.0 * x], [-2.0 * y, 2.0 * x, 0.0]]),
        contract([
            [0.0, 2.0 * y, 2.0 * z],
            [2.0 * y, -4.0 * x, -2.0 * w],
            [2.0 * z, 2.0 * w, -4.0 * x],
        ]),
        contract([
            [-4.0 * y, 2.0 * x, 2.0 * w],
            [2.0 * x, 0.0, 2.0 * z],
            [-2.0 * w, 2.0 * z, -4.0 * y],
        ]),
        contract([
            [-4.0 * z, -2.0 * w, 2.0 * x],
            [2.0 * w, -4.0 * z, 2.0 * y],
            [2.0 * x, 2.0 * y, 0.0],
        ]),
    ]
}

/// Vector–Jacobian product of [`project`]: gradients on the projected quantities → gradients
/// on the parameters. Only called for Gaussians that `project` accepted.
pub(crate) fn project_backward(
    view: &View,
    mean: [f32; 3],
    log_scale: [f32; 3],
    rotation: [f32; 4],
    projected: &Projected,
    grad: &ProjectedGrad,
) -> ParamGrad {
    let Some(g) = geometry(view, mean, log_scale, rotation) else {
        return ParamGrad::default();
    };
    let o = projected.opacity;
    let logit_opacity = grad.opacity * o * (1.0 - o);

    // Conic Q = Σ2d⁻¹: dL/dΣ2d = −Q G_Q Q with G_Q the symmetric matrix of dL/dQ.
    let [ca, cb, cc] = projected.conic;
    let q_mat = Mat2::from_cols(Vec2::new(ca, cb), Vec2::new(cb, cc));
    let [ga, gb, gc] = grad.conic;
    let g_q = Mat2::from_cols(Vec2::new(ga, 0.5 * gb), Vec2::new(0.5 * gb, gc));
    let g_cov = -(q_mat * g_q * q_mat);

    // Σ2d = J V Jᵀ: dL/dJ = 2 G J V, dL/dV = Jᵀ G J.
    let (g00, g01, g11) = (g_cov.x_axis.x, g_cov.y_axis.x, g_cov.y_axis.y);
    let gj = [g.j[0] * g00 + g.j[1] * g01, g.j[0] * g01 + g.j[1] * g11];
    let g_j = [2.0 * (g.v * gj[0]), 2.0 * (g.v * gj[1])];
    let outer = |a: Vec3, b: Vec3| Mat3::from_cols(a * b.x, a * b.y, a * b.z);
    let g_v = outer(g.j[0], gj[0]) + outer(g.j[1], gj[1]);
    let g_sigma = view.rot.transpose() * g_v * view.rot;

    // Σ = M Mᵀ, M = R diag(s): dL/dM = 2 G_Σ M (G_Σ symmetric).
    let g_m = 2.0 * (g_sigma * g.m);
    let g_r =
        Mat3::from_cols(g_m.x_axis * g.scale.x, g_m.y_axis * g.scale.y, g_m.z_axis * g.scale.z);
    let log_scale = [
        g_m.x_axis.dot(g.r.x_axis) * g.scale.x,
        g_m.y_axis.dot(g.r.y_axis) * g.scale.y,
        g_m.z_axis.dot(g.r.z_axis) * g.scale.z,
    ];
    let rotation = quaternion_vjp(g.q, g.q_norm, g_r);

    // Jacobian entries in terms of (tx, ty, z), tx and ty clamped.
    let (fx, fy) = (view.fx, view.fy);
    let z = g.p_cam.z;
    let (tx, ty) = (g.t_clamped.x, g.t_clamped.y);
    let (rz2, rz3) = (1.0 / (z * z), 1.0 / (z * z * z));
    let g_tx = -fx * rz2 * g_j[0].z;
    let g_ty = -fy * rz2 * g_j[1].z;
    let mut g_p = Vec3::new(0.0, 0.0, grad.depth);
    g_p.z += -fx * rz2 * g_j[0].x - fy * rz2 * g_j[1].y
        + 2.0 * fx * tx * rz3 * g_j[0].z
        + 2.0 * fy * ty * rz3 * g_j[1].z;
    // Unclamped: t = p; clamped: t = z·lim, so only z moves it.
    if g.clamped[0] {
        g_p.z += g_tx * tx / z;
    } else {
        g_p.x += g_tx;
    }
    if g.clamped[1] {
        g_p.z += g_ty * ty / z;
    } else {
        g_p.y += g_ty;
    }
    // Mean in pixels: u = fx x/z + cx.
    let [gu, gv] = grad.xy;
    g_p.x += gu * fx / z;
    g_p.y += gv * fy / z;
    g_p.z -= (gu * fx * g.p_cam.x + gv * fy * g.p_cam.y) * rz2;

    // Camera: p = W μ + t and V = W Σ Wᵀ, so dL/dW = g_p μᵀ + 2 G_V W Σ.
    let sigma = g.m * g.m.transpose();
    let view_rot = outer(g_p, Vec3::from(mean)) + 2.0 * (g_v * view.rot * sigma);
    ParamGrad {
        mean: (view.rot.transpose() * g_p).to_array(),
        log_scale,
        rotation,
        logit_opacity,
        view_rot: view_rot.to_cols_array(),
        view_trans: g_p.to_array(),
    }
}
