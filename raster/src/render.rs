//! The differentiable Gaussian rasterizer: the CPU tile renderer (forward and hand-written
//! backward, any number of feature channels in one pass, plus expected depth and accumulated
//! alpha) and, behind the `gpu` feature, a wgpu forward renderer for serving.
//!
//! Pipeline (CPU): every Gaussian is projected with the EWA Jacobian and its 2D covariance is
//! dilated by [`LOW_PASS`] = 0.3 px (the plain low-pass filter of gsplat and brush, without the
//! Mip-Splatting opacity compensation); Gaussians are binned into [`TILE`]×[`TILE`] tiles,
//! each tile's list sorted by camera depth; tiles are composited front to back in parallel
//! (rayon), four pixels of a row at a time (SIMD lanes), with the brush/gsplat constants of
//! STYLE.md. A Gaussian whose centre is nearer
//! than [`NEAR_PLANE`], whose quaternion is (near) zero, that has any non-finite parameter
//! or feature, or whose covariance overflows f32 (log-scales beyond ~20) is skipped: it draws
//! nothing and gets zero gradient. Output never holds NaN for finite cameras and backgrounds,
//! which are checked up front. Everything is f32: a Gaussian whose scales differ by more than
//! ~1e3 loses its thin axis to rounding in Σ = M Mᵀ (as in gsplat and brush).
//!
//! For a pixel with front-to-back Gaussians k: α_k = min(o_k·G_k, 0.999) when o_k·G_k ≥ 1/255
//! (else skipped), T_k = Π_{j<k}(1 − α_k), w_k = α_k·T_k; compositing stops before the
//! Gaussian that would take T below 1e-4. Outputs: F_c = Σ w_k f_kc + T·bg_c, alpha = 1 − T,
//! depth = Σ w_k z_k / max(Σ w_k, 1e-10) with Σ w_k = 1 − T.
//!
//! The backward ([`render_backward`]) gives gradients w.r.t. means, log-scales, quaternions
//! (through their normalization), logit opacities, every feature channel and the camera pose.
//! It keeps from the forward only the per-tile sorted lists, the projections, and per pixel
//! the final transmittance and the index of the last contributing Gaussian (as gsplat does).
//!
//! The wgpu renderer ([`GpuRenderer`]) shares projection and binning with the CPU path and
//! composites on the device; [`render_any`] uses it when given one and says which ran. On a
//! software adapter (lavapipe) the CPU path is faster; [`GpuRenderer::is_software`] tells.

mod backward;
mod composite;
#[cfg(feature = "gpu")]
mod gpu;
mod ids;
mod lanes;
mod project;
mod tiles;

use inssplat_proto::Camera;
use rayon::prelude::*;

#[cfg(feature = "gpu")]
pub use gpu::GpuRenderer;
pub use ids::{IdImage, render_ids, render_ids_any};
use project::{Projected, View};
use tiles::TileBins;

/// Tile edge in pixels.
pub const TILE: u32 = 16;
/// Alpha below which a Gaussian is skipped at a pixel.
pub const ALPHA_MIN: f32 = 1.0 / 255.0;
/// Largest alpha one Gaussian can have at a pixel.
pub const ALPHA_MAX: f32 = 0.999;
/// A pixel stops compositing before transmittance would drop below this.
pub const T_MIN: f32 = 1e-4;
/// Gaussians whose centre is nearer than this (camera z, world units) are skipped.
pub const NEAR_PLANE: f32 = 0.01;
/// Variance in pixels² added to every projected 2D covariance (anti-aliasing low pass).
pub const LOW_PASS: f32 = 0.3;

/// `n` Gaussians in the world frame, structure of arrays.
#[derive(Debug, Clone, Copy)]
pub struct Splats<'a> {
    pub means: &'a [[f32; 3]],
    pub log_scales: &'a [[f32; 3]],
    /// Quaternions w, x, y, z; normalized inside, need not be unit.
    pub rotations: &'a [[f32; 4]],
    pub logit_opacity: &'a [f32],
    /// `n × channels`, row-major per Gaussian.
    pub features: &'a [f32],
    pub channels: usize,
}

/// A rendered view.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub channels: usize,
    /// Channel-planar: `[channels][height][width]`.
    pub features: Vec<f32>,
    /// `[height][width]` expected depth, 0 where alpha is 0.
    pub depth: Vec<f32>,
    /// `[height][width]` accumulated alpha, 1 − final transmittance.
    pub alpha: Vec<f32>,
}

/// Gradients of a loss w.r.t. every Gaussian parameter, shaped like [`Splats`], and w.r.t.
/// the camera pose.
#[derive(Debug, Clone, PartialEq)]
pub struct SplatGrads {
    pub means: Vec<[f32; 3]>,
    pub log_scales: Vec<[f32; 3]>,
    pub rotations: Vec<[f32; 4]>,
    pub logit_opacity: Vec<f32>,
    pub features: Vec<f32>,
    pub camera: CameraGrad,
}

/// Gradient w.r.t. the camera's world → camera pose (intrinsics are not differentiated).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CameraGrad {
    /// W.r.t. the components w, x, y, z of `Camera::rotation` (normalized inside).
    pub rotation: [f32; 4],
    pub translation: [f32; 3],
}

/// How alpha behaves at the 1/255 cutoff.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AlphaCutoff {
    /// α = 0 below 1/255, as in gsplat and brush. What rendering uses.
    #[default]
    Hard,
    /// α = v·smoothstep((v − 0.5/255)·255): zero below 0.5/255, exact above 1.5/255, so the
    /// image is a smooth function of the parameters. For finite-difference gradient tests
    /// only, where the jump of the hard cutoff would make the differences meaningless.
    Smooth,
}

/// Options of [`render_with`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RenderOptions {
    pub cutoff: AlphaCutoff,
}

/// Which renderer produced an image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    Cpu,
    Wgpu,
}

/// Why a render could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RenderError {
    #[error("splat field `{field}` has {got} entries, expected {expected}")]
    Length { field: &'static str, expected: usize, got: usize },
    #[error("background has {got} values; expected {expected} (one per channel) or none")]
    Background { expected: usize, got: usize },
    #[error("background value {0} is not finite")]
    NonFiniteBackground(f32),
    #[error("image size {width}×{height} is empty")]
    EmptyImage { width: u32, height: u32 },
    #[error("camera is unusable: {0}")]
    Camera(&'static str),
    #[error("no wgpu adapter found")]
    NoAdapter,
    #[error("wgpu: {0}")]
    Gpu(String),
}

/// What the backward needs from a forward pass.
#[derive(Debug, Clone)]
pub struct ForwardState {
    view: View,
    width: u32,
    height: u32,
    channels: usize,
    cutoff: AlphaCutoff,
    background: Vec<f32>,
    /// Per Gaussian; `None` where skipped.
    projected: Vec<Option<Projected>>,
    bins: TileBins,
    /// Per pixel: final transmittance, one past the last contributing list entry, and the
    /// rendered expected depth.
    transmittance: Vec<f32>,
    last: Vec<u32>,
    depth: Vec<f32>,
}

impl ForwardState {
    /// Number of (tile, Gaussian) pairs the forward composited over.
    pub fn intersections(&self) -> usize {
        self.bins.rank_from_isect.len()
    }
}

/// Checks the inputs and returns the background padded to `channels` values.
fn validate(splats: &Splats, camera: &Camera, background: &[f32]) -> Result<Vec<f32>, RenderError> {
    let n = splats.means.len();
    let lengths = [
        ("log_scales", n, splats.log_scales.len()),
        ("rotations", n, splats.rotations.len()),
        ("logit_opacity", n, splats.logit_opacity.len()),
        ("features", n * splats.channels, splats.features.len()),
    ];
    if let Some(&(field, expected, got)) = lengths.iter().find(|(_, e, g)| e != g) {
        return Err(RenderError::Length { field, expected, got });
    }
    let k = &camera.intrinsics;
    if k.width == 0 || k.height == 0 {
        return Err(RenderError::EmptyImage { width: k.width, height: k.height });
    }
    if ![k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite()) || k.fx <= 0.0 || k.fy <= 0.0 {
        return Err(RenderError::Camera("intrinsics must be finite with positive focal lengths"));
    }
    if !camera.rotation.is_finite()
        || camera.rotation.length() < 1e-6
        || !camera.translation.is_finite()
    {
        return Err(RenderError::Camera("pose must be finite with a nonzero rotation"));
    }
    match background.len() {
        0 => Ok(vec![0.0; splats.channels]),
        len if len == splats.channels => match background.iter().find(|v| !v.is_finite()) {
            Some(&v) => Err(RenderError::NonFiniteBackground(v)),
            None => Ok(background.to_vec()),
        },
        got => Err(RenderError::Background { expected: splats.channels, got }),
    }
}

/// Projects and bins: the part of the forward that the CPU and wgpu paths share.
fn prepare(
    splats: &Splats,
    view: &View,
    cutoff: AlphaCutoff,
    width: u32,
    height: u32,
) -> (Vec<Option<Projected>>, TileBins) {
    let c = splats.channels;
    let projected: Vec<Option<Projected>> = (0..splats.means.len())
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| {
            if !splats.features[i * c..(i + 1) * c].iter().all(|v| v.is_finite()) {
                return None;
            }
            project::project(
                view,
                splats.means[i],
                splats.log_scales[i],
                splats.rotations[i],
                splats.logit_opacity[i],
                cutoff.floor(),
            )
        })
        .collect();
    let bins = tiles::bin(&projected, splats.features, c, width, height);
    (projected, bins)
}

/// Composites every tile of `bins` (in parallel), each into a fresh sink from `sink`, and
/// returns `finish(sink, coverage)` per tile, in tile order.
fn composite_tiles<S: composite::TileSink, T: Send>(
    bins: &TileBins,
    cutoff: AlphaCutoff,
    size: [u32; 2],
    sink: impl Fn() -> S + Sync,
    finish: impl Fn(S, composite::TileCoverage) -> T + Sync,
) -> Vec<T> {
    (0..bins.tile_count())
        .into_par_iter()
        .map(|tile| {
            let origin = [(tile as u32 % bins.tiles_x) * TILE, (tile as u32 / bins.tiles_x) * TILE];
            let mut s = sink();
            let cov = composite::composite_tile(
                bins.isects(tile),
                &bins.sorted,
                cutoff,
                origin,
                size,
                &mut s,
            );
            finish(s, cov)
        })
        .collect()
}

/// Renders with the hard alpha cutoff; see [`render_with`].
pub fn render(
    splats: &Splats,
    camera: &Camera,
    background: &[f32],
) -> Result<(Image, ForwardState), RenderError> {
    render_with(splats, camera, background, &RenderOptions::default())
}

/// Renders `splats` seen by `camera` on the CPU over `background` (one value per channel, or
/// empty for zeros). Returns the image and what [`render_backward`] needs.
pub fn render_with(
    splats: &Splats,
    camera: &Camera,
    background: &[f32],
    options: &RenderOptions,
) -> Result<(Image, ForwardState), RenderError> {
    let background = validate(splats, camera, background)?;
    let (width, height) = (camera.intrinsics.width, camera.intrinsics.height);
    let c = splats.channels;
    let view = View::new(camera);
    let (projected, bins) = prepare(splats, &view, options.cutoff, width, height);

    let tiles = composite_tiles(
        &bins,
        options.cutoff,
        [width, height],
        || composite::FeatureSink::new(&bins.sorted_features, c),
        |sink, cov| {
            let (features, depth) = sink.into_planes(&cov, &background);
            (cov, features, depth)
        },
    );

    let (w, pixels) = (width as usize, width as usize * height as usize);
    let tiles_x = bins.tiles_x as usize;
    let mut image = Image {
        width,
        height,
        channels: c,
        features: vec![0.0; c * pixels],
        depth: vec![0.0; pixels],
        alpha: vec![0.0; pixels],
    };
    let mut transmittance = vec![1.0; pixels];
    let mut last = vec![0; pixels];
    let alphas: Vec<[f32; composite::TILE_PIXELS]> =
        tiles.iter().map(|(cov, ..)| cov.transmittance.map(|t| 1.0 - t)).collect();
    // One task per output plane: features, then depth, alpha and transmittance.
    let mut planes: Vec<&mut [f32]> = image.features.chunks_exact_mut(pixels).collect();
    planes.extend([&mut image.depth[..], &mut image.alpha[..], &mut transmittance[..]]);
    planes.into_par_iter().enumerate().for_each(|(i, plane)| {
        tiles::untile(plane, w, tiles_x, |t| match i.checked_sub(c) {
            None => &tiles[t].1[i * composite::TILE_PIXELS..(i + 1) * composite::TILE_PIXELS],
            Some(0) => &tiles[t].2,
            Some(1) => &alphas[t],
            Some(_) => &tiles[t].0.transmittance,
        })
    });
    tiles::untile(&mut last, w, tiles_x, |t| &tiles[t].0.last);
    let state = ForwardState {
        view,
        width,
        height,
        channels: c,
        cutoff: options.cutoff,
        background,
        projected,
        bins,
        transmittance,
        last,
        depth: image.depth.clone(),
    };
    Ok((image, state))
}

/// Gradients of a loss w.r.t. every parameter of `splats`, given the loss's gradients on the
/// outputs of the forward that produced `state` (same splats, same camera): `d_features`
/// channel-planar like [`Image::features`], `d_depth` and `d_alpha` per pixel.
///
/// # Panics
/// If a gradient buffer does not have the size of the corresponding output, or `splats`
/// does not have as many Gaussians and channels as the forward saw.
pub fn render_backward(
    splats: &Splats,
    camera: &Camera,
    state: &ForwardState,
    d_features: &[f32],
    d_depth: &[f32],
    d_alpha: &[f32],
) -> SplatGrads {
    let pixels = state.width as usize * state.height as usize;
    assert_eq!(
        d_features.len(),
        pixels * state.channels,
        "d_features must be [channels][height][width]"
    );
    assert_eq!(d_depth.len(), pixels, "d_depth must be [height][width]");
    assert_eq!(d_alpha.len(), pixels, "d_alpha must be [height][width]");
    assert_eq!(splats.means.len(), state.projected.len(), "splats differ from the forward's");
    assert_eq!(splats.channels, state.channels, "channel count differs from the forward's");
    assert_eq!(
        (camera.intrinsics.width, camera.intrinsics.height),
        (state.width, state.height),
        "camera differs from the forward's"
    );
    backward::backward(splats, camera, state, d_features, d_depth, d_alpha)
}

/// Renders on `gpu` when given and working, else on the CPU; says which one ran. Errors in
/// the input are returned as they are; a failing device falls back to the CPU.
pub fn render_any(
    gpu: Option<&GpuRenderer>,
    splats: &Splats,
    camera: &Camera,
    background: &[f32],
) -> Result<(Image, Backend), RenderError> {
    if let Some(gpu) = gpu {
        match gpu.render(splats, camera, background) {
            Ok(image) => return Ok((image, Backend::Wgpu)),
            Err(RenderError::Gpu(_) | RenderError::NoAdapter) => {}
            Err(e) => return Err(e),
        }
    }
    render(splats, camera, background).map(|(image, _)| (image, Backend::Cpu))
}

/// Built without the `gpu` feature there is no GPU renderer: this type has no values and
/// [`GpuRenderer::new`] always answers [`RenderError::NoAdapter`].
#[cfg(not(feature = "gpu"))]
#[derive(Debug)]
pub enum GpuRenderer {}

#[cfg(not(feature = "gpu"))]
impl GpuRenderer {
    pub fn new() -> Result<Self, RenderError> {
        Err(RenderError::NoAdapter)
    }

    pub fn render(&self, _: &Splats, _: &Camera, _: &[f32]) -> Result<Image, RenderError> {
        match *self {}
    }

    pub fn adapter(&self) -> String {
        match *self {}
    }

    pub fn is_software(&self) -> bool {
        match *self {}
    }
}
