//! The backward pass: tiles walked back to front, recovering each pixel's transmittance
//! from the final one (T_k = T_{k+1} / (1 − α_k)) instead of storing it, as gsplat does.
//! Each tile writes the gradient it owes every Gaussian of its list into that list entry's
//! own slot (no atomics, and sums happen in a fixed order, so results do not depend on the
//! thread count); the slots are then summed per Gaussian and pushed through the projection.
//! Like the forward, the walk handles four pixels of a row at a time (`wide::f32x4` lanes,
//! masked where a pixel is outside the Gaussian's span or already finished): the incoming
//! feature gradients are kept channel-planar so that a channel of four pixels is one load.
//! Of the features composited behind a Gaussian the walk carries only their dot product with
//! the pixel's incoming gradient, one number per pixel instead of one per channel.

use glam::Mat3;
use inssplat_proto::Camera;
use rayon::prelude::*;
use wide::{f32x4, u32x4};

use super::composite::{Ellipse, TILE_PIXELS, pixel_offset, span};
use super::lanes::{LANES, chunk_starts, column_offsets, gaussian_values, span_mask};
use super::project::{ProjectedGrad, project_backward, quaternion_vjp};
use super::{CameraGrad, ForwardState, SplatGrads, Splats, TILE};

/// Per-pixel arrays of a tile, with room for the lanes a group may reach past its last pixel.
const PADDED: usize = TILE_PIXELS + LANES;

/// Four consecutive pixels of `a` from `p`.
#[inline(always)]
fn load(a: &[f32], p: usize) -> f32x4 {
    f32x4::new(a[p..p + LANES].try_into().unwrap())
}

/// Writes four consecutive pixels of `a` from `p`.
#[inline(always)]
fn store(a: &mut [f32], p: usize, v: f32x4) {
    a[p..p + LANES].copy_from_slice(v.as_array());
}

/// Per-pixel gradients on the raw sums the compositor forms, row-major within a tile.
struct TileGrads {
    /// dL/dF, channel-planar: `[channel][PADDED]`.
    features: Vec<f32>,
    /// dL/d(Σ w·z).
    depth_sum: [f32; PADDED],
    /// dL/d(1 − T_final), the depth normalization folded in.
    alpha: [f32; PADDED],
}

/// Number of gradient slots per intersection before the feature channels: x, y, conic a, b,
/// c, opacity, depth.
const GEOM: usize = 7;

/// Gathers a tile's incoming gradients and folds expected depth D = S / max(A, 1e-10) into
/// gradients on S and on A.
fn tile_grads(
    state: &ForwardState,
    tile: usize,
    d_features: &[f32],
    d_depth: &[f32],
    d_alpha: &[f32],
) -> TileGrads {
    let c = state.channels;
    let (w, h) = (state.width as usize, state.height as usize);
    let (tx, ty) = (tile % state.bins.tiles_x as usize, tile / state.bins.tiles_x as usize);
    let mut g = TileGrads {
        features: vec![0.0; c * PADDED],
        depth_sum: [0.0; PADDED],
        alpha: [0.0; PADDED],
    };
    for ly in 0..TILE as usize {
        let y = ty * TILE as usize + ly;
        if y >= h {
            break;
        }
        for lx in 0..TILE as usize {
            let x = tx * TILE as usize + lx;
            if x >= w {
                break;
            }
            let (p, pix) = (ly * TILE as usize + lx, y * w + x);
            for ch in 0..c {
                g.features[ch * PADDED + p] = d_features[ch * w * h + pix];
            }
            let alpha = 1.0 - state.transmittance[pix];
            let denom = alpha.max(1e-10);
            g.depth_sum[p] = d_depth[pix] / denom;
            let through_norm =
                if alpha > 1e-10 { d_depth[pix] * state.depth[pix] / alpha } else { 0.0 };
            g.alpha[p] = d_alpha[pix] - through_norm;
        }
    }
    g
}

/// Walks one tile back to front; writes each list entry's gradient slot
/// (`GEOM + channels` floats per entry) into `slots`.
fn backward_tile(state: &ForwardState, tile: usize, grads: &TileGrads, slots: &mut [f32]) {
    let c = state.channels;
    let stride = GEOM + c;
    let (w, h) = (state.width as usize, state.height as usize);
    let origin = [
        (tile % state.bins.tiles_x as usize) as u32 * TILE,
        (tile / state.bins.tiles_x as usize) as u32 * TILE,
    ];
    let ranks = state.bins.isects(tile);
    let mut t = [0.0f32; PADDED];
    let mut t_final = [0.0f32; PADDED];
    let mut last = [0u32; PADDED];
    // dL/dF · (Σ over later Gaussians of w·f + T_final·bg) per pixel: the dot product is
    // carried instead of the sum, since each step adds w·(dL/dF · f), which the pair needs
    // anyway.
    let mut buf_dot = [0.0f32; PADDED];
    let mut buf_depth = [0.0f32; PADDED];
    for p in 0..TILE_PIXELS {
        let (x, y) =
            (origin[0] as usize + p % TILE as usize, origin[1] as usize + p / TILE as usize);
        if x < w && y < h {
            let pix = y * w + x;
            t[p] = state.transmittance[pix];
            t_final[p] = t[p];
            last[p] = state.last[pix];
            let bg_dot: f32 =
                (0..c).map(|ch| grads.features[ch * PADDED + p] * state.background[ch]).sum();
            buf_dot[p] = t[p] * bg_dot;
        }
    }
    // Per channel, the feature gradient the current Gaussian collects, one lane per column.
    let mut g_features = vec![f32x4::ZERO; c];
    let row_last: Vec<u32> =
        last.chunks(TILE as usize).map(|row| row.iter().copied().max().unwrap_or(0)).collect();
    let end = row_last.iter().copied().max().unwrap_or(0) as usize;
    for k in (0..end).rev() {
        let rank = ranks[k] as usize;
        let g = &state.bins.sorted[rank];
        let Some((y0, y1)) = span(g.xy[1], g.extent[1], origin[1]) else { continue };
        let f = &state.bins.sorted_features[rank * c..(rank + 1) * c];
        g_features.fill(f32x4::ZERO);
        // The geometry slots, lane sums: x, y, conic a, b, c, opacity (before its 1/o), depth.
        let mut geom = [f32x4::ZERO; GEOM];
        let [a, b, cc] = g.conic;
        let depth = f32x4::splat(g.depth);
        let stamp = u32x4::splat(k as u32);
        let ellipse = Ellipse::new(g);
        for (y, &row_end) in row_last.iter().enumerate().take(y1 + 1).skip(y0) {
            if k as u32 >= row_end {
                continue;
            }
            let dy = pixel_offset(origin[1], y, g.xy[1]);
            let Some((x0, x1)) = ellipse.row_span(dy, origin[0]) else { continue };
            for base in chunk_starts(x0, x1) {
                let p = y * TILE as usize + base;
                let v = gaussian_values(g, origin[0], base, dy);
                let (alpha, slope) = state.cutoff.alpha_and_slope_lanes(v);
                // Lanes of this row's span, not past the pixel's last contributor, with α > 0.
                let live = u32x4::new(last[p..p + LANES].try_into().unwrap()).simd_gt(stamp);
                let on =
                    f32x4::from_bits(span_mask(base, x0, x1) & live) & alpha.simd_gt(f32x4::ZERO);
                if on.to_bitmask() == 0 {
                    continue;
                }
                let alpha = on.select(alpha, f32x4::ZERO);
                // α ≤ 0.999, so 1/(1 − α) ≤ 1000.
                let inv = f32x4::ONE / (f32x4::ONE - alpha);
                let t_p = load(&t, p);
                let t_k = t_p * inv;
                store(&mut t, p, on.select(t_k, t_p));
                let weight = alpha * t_k;
                // dF_c/dα = T_k f_c − (Σ_{later} w f_c + T_final bg_c) / (1 − α).
                let mut dot_f = f32x4::ZERO;
                for ((ch, &fc), acc) in f.iter().enumerate().zip(&mut g_features) {
                    let gf = load(&grads.features[ch * PADDED..], p);
                    dot_f += gf * fc;
                    *acc += gf * weight;
                }
                let buf_dot_p = load(&buf_dot, p);
                let buf_depth_p = load(&buf_depth, p);
                let depth_sum = load(&grads.depth_sum, p);
                let mut g_alpha = t_k * dot_f - inv * buf_dot_p;
                g_alpha += depth_sum * (t_k * depth - buf_depth_p * inv);
                g_alpha += load(&grads.alpha, p) * load(&t_final, p) * inv;
                store(&mut buf_dot, p, buf_dot_p + weight * dot_f);
                store(&mut buf_depth, p, buf_depth_p + weight * depth);
                geom[6] += depth_sum * weight;

                // v = o·exp(power): dv/do = v/o, dv/dpower = v.
                let g_power = on.select(g_alpha * slope * v, f32x4::ZERO);
                let dx = column_offsets(origin[0], base, g.xy[0]);
                geom[5] += g_power;
                // power = −½(a dx² + 2b dx dy + c dy²), dx = px − u.
                geom[0] += g_power * (dx * a + b * dy);
                geom[1] += g_power * (dx * b + cc * dy);
                geom[2] -= g_power * dx * dx * 0.5;
                geom[3] -= g_power * dx * dy;
                geom[4] -= g_power * (0.5 * dy * dy);
            }
        }
        let mut sums = geom.map(f32x4::reduce_add);
        if sums[5] != 0.0 {
            sums[5] /= g.opacity;
        }
        let slot = &mut slots[k * stride..(k + 1) * stride];
        slot[..GEOM].copy_from_slice(&sums);
        for (dst, acc) in slot[GEOM..].iter_mut().zip(&g_features) {
            *dst = acc.reduce_add();
        }
    }
}

/// The whole backward; see [`super::render_backward`].
pub(crate) fn backward(
    splats: &Splats,
    camera: &Camera,
    state: &ForwardState,
    d_features: &[f32],
    d_depth: &[f32],
    d_alpha: &[f32],
) -> SplatGrads {
    let c = state.channels;
    let stride = GEOM + c;
    let n = splats.means.len();
    let mut slots = vec![0.0f32; state.bins.rank_from_isect.len() * stride];
    // Split the slot array at tile boundaries so each tile owns its entries.
    let mut per_tile: Vec<(usize, &mut [f32])> = Vec::with_capacity(state.bins.tile_count());
    let mut rest = slots.as_mut_slice();
    for tile in 0..state.bins.tile_count() {
        let len = state.bins.isects(tile).len() * stride;
        let (mine, tail) = rest.split_at_mut(len);
        per_tile.push((tile, mine));
        rest = tail;
    }
    per_tile.into_par_iter().for_each(|(tile, mine)| {
        if mine.is_empty() {
            return;
        }
        let grads = tile_grads(state, tile, d_features, d_depth, d_alpha);
        backward_tile(state, tile, &grads, mine);
    });

    // Sum slots per Gaussian in a fixed order (by intersection index): each thread owns a
    // range of Gaussians and walks the whole intersection list for the entries of its range.
    let mut projected_grads = vec![ProjectedGrad::default(); n];
    let mut features = vec![0.0f32; n * c];
    let per_part = n.div_ceil(rayon::current_num_threads()).max(1);
    // One feature range per part, empty ones when there are no channels.
    let mut feature_parts: Vec<&mut [f32]> = features.chunks_mut((per_part * c).max(1)).collect();
    feature_parts.resize_with(n.div_ceil(per_part), Default::default);
    let parts = projected_grads.par_chunks_mut(per_part).zip(feature_parts);
    parts.enumerate().for_each(|(part, (pgs, feats))| {
        let owned = part * per_part..part * per_part + pgs.len();
        for (isect, &rank) in state.bins.rank_from_isect.iter().enumerate() {
            let gid = state.bins.gid_from_rank[rank as usize] as usize;
            if !owned.contains(&gid) {
                continue;
            }
            let i = gid - owned.start;
            let s = &slots[isect * stride..(isect + 1) * stride];
            let pg = &mut pgs[i];
            pg.xy[0] += s[0];
            pg.xy[1] += s[1];
            pg.conic[0] += s[2];
            pg.conic[1] += s[3];
            pg.conic[2] += s[4];
            pg.opacity += s[5];
            pg.depth += s[6];
            for (dst, src) in feats[i * c..(i + 1) * c].iter_mut().zip(&s[GEOM..]) {
                *dst += src;
            }
        }
    });

    // The projection's vector–Jacobian product is linear in the incoming gradient, so a
    // Gaussian that reached no pixel (outside the view, or behind opaque ones) owes nothing.
    let params: Vec<_> = (0..n)
        .into_par_iter()
        .map(|i| match state.projected[i].as_ref() {
            Some(p) if !projected_grads[i].is_zero() => project_backward(
                &state.view,
                splats.means[i],
                splats.log_scales[i],
                splats.rotations[i],
                p,
                &projected_grads[i],
            ),
            _ => Default::default(),
        })
        .collect();
    // The camera's gradient sums every Gaussian's share; the view used the normalized
    // rotation, so the quaternion gradient goes through that normalization.
    let (mut g_rot, mut g_trans) = ([0.0f32; 9], [0.0f32; 3]);
    for p in &params {
        g_rot.iter_mut().zip(&p.view_rot).for_each(|(a, b)| *a += b);
        g_trans.iter_mut().zip(&p.view_trans).for_each(|(a, b)| *a += b);
    }
    let q = camera.rotation;
    let norm = q.length();
    let unit = [q.w / norm, q.x / norm, q.y / norm, q.z / norm];
    let camera = CameraGrad {
        rotation: quaternion_vjp(unit, norm, Mat3::from_cols_array(&g_rot)),
        translation: g_trans,
    };
    SplatGrads {
        camera,
        means: params.iter().map(|p| p.mean).collect(),
        log_scales: params.iter().map(|p| p.log_scale).collect(),
        rotations: params.iter().map(|p| p.rotation).collect(),
        logit_opacity: params.iter().map(|p| p.logit_opacity).collect(),
        features,
    }
}
