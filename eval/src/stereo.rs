//! `inssplat-eval stereo OUT`: what `inssplat reconstruct` made of a rectified stereo pair,
//! against the first photo's true disparity as Middlebury gives it. The depth of view 0 is
//! scored as AbsRel after median scaling (photos alone fix no scale) on the pixels whose
//! disparity is known, the truth's depth being focal × baseline / (disparity + doffs), of which
//! the median scaling takes out the focal length and baseline; and the registered second
//! camera's direction from the first against the true one, the first camera's x axis.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use inssplat_metrics::image::depth_abs_rel;
use inssplat_proto::dataset::Scene;
use serde::Serialize;

/// How the first view's depth compares with the truth.
#[derive(Debug, Clone, Serialize)]
pub struct StereoScore {
    /// Pixels with a known disparity and a predicted depth.
    pub pixels: usize,
    /// AbsRel with the prediction scaled by its median ratio to the truth.
    pub abs_rel: f64,
    /// Angle between the registered step from the first camera to the second and the true
    /// one (the first camera's x axis), degrees.
    pub baseline_off_deg: f64,
}

/// The truth's disparity: the first array of a `.npz` (as scikit-image ships Middlebury's
/// motorcycle), `[H][W]` float32 photo pixels, unknown where not finite or not positive.
pub fn read_disparity(path: &Path) -> anyhow::Result<(usize, usize, Vec<f32>)> {
    use ndarray_npy::NpzReader;
    let file =
        std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut npz =
        NpzReader::new(file).with_context(|| format!("{}: not a .npz archive", path.display()))?;
    let name = npz
        .names()
        .with_context(|| format!("{}: unreadable .npz", path.display()))?
        .into_iter()
        .next()
        .with_context(|| format!("{}: the .npz holds no array", path.display()))?;
    let array: ndarray::Array2<f32> = npz
        .by_name(&name)
        .with_context(|| format!("{}: array {name} is not a 2-D float32 image", path.display()))?;
    let (h, w) = array.dim();
    Ok((w, h, array.iter().copied().collect()))
}

/// Scores the output folder `out` against the disparity at `truth` of a pair whose principal
/// points lie `doffs` pixels apart.
pub fn score(out: &Path, truth: &Path, doffs: f64) -> anyhow::Result<StereoScore> {
    let scene = Scene::load(out)?;
    let [left, right, ..] = scene.frames.as_slice() else {
        bail!("{}: a stereo pair needs two views; this scene has one", out.display());
    };
    let json = || PathBuf::from(out).join("transforms.json").display().to_string();
    let depth = left
        .depth
        .as_ref()
        .with_context(|| format!("{}: frames[0] has no depth_file_path", json()))?;
    let (w, h, disparity) = read_disparity(truth)?;
    if (w as u32, h as u32) != (left.width(), left.height()) {
        bail!(
            "{}: the disparity is {w}×{h}, the first photo {}×{}",
            truth.display(),
            left.width(),
            left.height()
        );
    }
    let truth_depth: Vec<f32> = disparity
        .iter()
        .map(|&d| {
            let z = 1.0 / (f64::from(d) + doffs);
            if d.is_finite() && d > 0.0 && z > 0.0 { z as f32 } else { 0.0 }
        })
        .collect();
    let depth = depth_abs_rel(depth, &truth_depth)?
        .with_context(|| format!("{}: no pixel has both a depth and a disparity", out.display()))?;
    let step = left.camera.world_to_camera(right.camera.center()).as_dvec3();
    if step.length() == 0.0 {
        bail!("{}: the two cameras are registered at one place", json());
    }
    let baseline_off_deg =
        step.normalize().dot(glam::DVec3::X).clamp(-1.0, 1.0).acos().to_degrees();
    Ok(StereoScore { pixels: depth.pixels, abs_rel: depth.abs_rel, baseline_off_deg })
}

/// The score as the command prints it.
pub fn describe(s: &StereoScore) -> String {
    format!(
        "depth of view 0 against the true disparity, {} pixels: AbsRel {:.3} at the median \
         scale\nthe second camera's step from the first: {:.1}° off the true baseline",
        s.pixels, s.abs_rel, s.baseline_off_deg
    )
}
