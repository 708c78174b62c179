//! The reconstruct pipeline as a sequence of stages ([`crate::stages`], one file each):
//! photos → decode → the object detector's boxes in each photo → network → instance embeddings
//! snapped to each photo's colour superpixels → register → the views no match links turned to
//! the heading where the linked views' Gaussians match their photos → (a network that reads
//! rays: its second pass on the registered cameras) → back-project → voxelize → cluster once in
//! 3D → each merged Gaussian given the id most of its pixels carry → per-view instance maps →
//! semantic prototypes, moved toward what the shape classifier makes of each instance and the
//! classes the detector's boxes vote for, named by text → (optionally) the Gaussians and
//! cameras refined against the photos, ids and names kept → the maps at the photos' size.
//! Every stage is timed by one [`Stopwatch`].

use inssplat_geometry::heading::HeadingParams;
use inssplat_geometry::refine::SceneRefinement;
use inssplat_geometry::register::RegisterParams;
use inssplat_geometry::voxel::{VoxelParams, VoxelReport};
use inssplat_proto::api::{CameraFit, FocalSource, InstanceOut, Placement, StageTiming};
use inssplat_proto::shape::DESCRIPTOR;
use inssplat_proto::signature::{MAX_VIEWS, MIN_VIEWS};
use inssplat_proto::{Camera, GaussianScene};
use inssplat_text::LabelCache;
use inssplat_understand::cluster::ClusterParams;
use inssplat_understand::cluster::split::SplitParams;
use inssplat_understand::label::{InstancePrototype, SemanticProjection};
use inssplat_understand::superpixel::SuperpixelParams;
use rayon::prelude::*;
use std::sync::Arc;

use crate::backend::{Backend, RuntimeError};
use crate::detector::{Detector, PRESHRINK};
use crate::matcher::LearnedMatcher;
use crate::stages::decode::{DecodeError, Letterbox, Sizes, decode_all};
use crate::stages::label::{DetectorEvidence, LabelInputs};
pub use crate::stages::network::Known;
use crate::stages::{
    Stopwatch, backproject, cameras, cluster, detect, heading, label, masks, network, rays, refine,
    superpixels, vote, voxelize,
};

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(
        "{0} images given; inssplat needs between {MIN_VIEWS} and {MAX_VIEWS} views of one scene"
    )]
    ViewCount(usize),
    #[error(transparent)]
    Decode(#[from] DecodeError),
    #[error(transparent)]
    Runtime(#[from] RuntimeError),
    #[error("label vocabulary is empty")]
    EmptyVocabulary,
    #[error("{given} known camera poses for {views} views; give one per view, in order")]
    Poses { given: usize, views: usize },
    #[error(
        "{given} known depth values for {views} views of {pixels} pixels; give one per pixel of every view at the model resolution"
    )]
    Depth { given: usize, views: usize, pixels: usize },
    #[error(
        "this network reads its cameras as rays: known camera poses need the scene's median depth in their units beside them"
    )]
    RaysNeedScale,
    #[error("{stage}: {message}")]
    Stage { stage: &'static str, message: String },
    #[error(
        "--photo-aspect: this network takes only the {resolution}×{resolution} square it was trained at (a file exported before 0.14); leave the switch off or export it again"
    )]
    SquareOnly { resolution: usize },
}

/// Default [`PipelineConfig::shape_weight`].
pub const DEFAULT_SHAPE_WEIGHT: f32 = 1.0;

/// Tunables of the post-processing stages.
#[derive(Debug, Clone)]
pub struct PipelineConfig {
    pub voxel: VoxelParams,
    pub cluster: ClusterParams,
    /// Split each clustered instance into its parts apart in 3D (`None`: keep the
    /// clustering's instances).
    pub split: Option<SplitParams>,
    /// Register the views from matched keypoints and the predicted depth (the "register"
    /// stage; views it cannot reach keep the camera head's pose). `None`: the camera head's
    /// poses as they are.
    pub register: Option<RegisterParams>,
    /// The learned matcher that registration matches keypoints with (XFeat + LighterGlue,
    /// loaded from `models/matcher/` by the binaries); `None`: FAST + BRIEF.
    pub matcher: Option<Arc<LearnedMatcher>>,
    /// The object detector whose boxes in the photos help name the instances (stage
    /// "detect", NanoDet loaded from `models/detector/` by the binaries); `None`: the
    /// network's features and the shape classifier alone.
    pub detector: Option<Arc<Detector>>,
    /// What is known of the views beforehand: nothing for a user's photos; the evaluation's
    /// oracles set the true cameras or depth.
    pub known: Known,
    /// With a network that reads its cameras as rays and no known poses: run it a second
    /// time on the rays of the registered cameras (stage "rays") and take its instance and
    /// semantic features from that pass; `false`: its first pass, with every ray zero, is all.
    pub ray_pass: bool,
    /// Weight of the shape classifier's text-space direction added to each instance's
    /// semantic prototype before naming (0, or a model without a classifier, names by the
    /// semantic features alone).
    pub shape_weight: f32,
    /// Adam steps of test-time refinement of the Gaussians and the input cameras (not
    /// [`Known::poses`]) against the input photos after the instances are
    /// clustered and named, which it keeps (stage "refine", [`inssplat_geometry::refine`]; 0, the
    /// default, is the feed-forward pipeline).
    pub refine_steps: usize,
    /// Snap each view's instance embeddings to its photo's colour superpixels before they
    /// are placed, and give every superpixel of an input view's instance map the id most of
    /// its pixels carry (stage "superpixels", [`inssplat_understand::superpixel`]; `None`: the
    /// network's maps as they are, and each pixel its own merged Gaussian's id).
    pub superpixels: Option<SuperpixelParams>,
    /// Turn each component of views that registration could not link to the first photo to
    /// the heading at which the linked views' Gaussians match its photos best (stage
    /// "heading", [`inssplat_geometry::heading`]; `None`: the continued poses stay).
    pub heading: Option<HeadingParams>,
    /// What the superpixel vote corrects (with [`PipelineConfig::superpixels`] only).
    pub vote: VoteScope,
    /// Long side, in pixels, of each input view's instance and label maps at the photo's
    /// resolution (the photo's own when it is smaller), upsampled from the model's along the
    /// photo's edges (stage "upsample", [`inssplat_understand::upsample`]); 0: the maps at the
    /// model's resolution only.
    pub mask_size: u32,
    /// Run the network on a patch grid of the photos' aspect (their long side at the model's
    /// resolution, [`crate::stages::decode::input_size`]) rather than on its trained square
    /// with grey bars; the network must take it ([`crate::backend::Network::size_multiple`]).
    pub photo_aspect: bool,
}

/// Default [`PipelineConfig::mask_size`].
pub const DEFAULT_MASK_SIZE: u32 = 1024;

/// Where the input views' superpixel vote (each superpixel takes the id most of its pixels
/// carry) is applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum VoteScope {
    /// The input views' masks alone; the Gaussians keep the clustering's ids.
    Masks,
    /// The merged Gaussians too, before they are named: each takes the voted id that most
    /// of the pixels merged into it carry, so the views rendered anew follow the vote too.
    Gaussians,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            voxel: VoxelParams::default(),
            cluster: ClusterParams::default(),
            split: Some(SplitParams::default()),
            register: Some(RegisterParams::default()),
            matcher: None,
            detector: None,
            known: Known::default(),
            ray_pass: true,
            shape_weight: DEFAULT_SHAPE_WEIGHT,
            refine_steps: 0,
            superpixels: Some(SuperpixelParams::default()),
            heading: Some(HeadingParams::default()),
            vote: VoteScope::Gaussians,
            mask_size: DEFAULT_MASK_SIZE,
            photo_aspect: false,
        }
    }
}

impl PipelineConfig {
    /// This configuration with a request's or job's own refinement steps, where it set them.
    pub fn with_refine_steps(&self, steps: Option<usize>) -> Self {
        Self { refine_steps: steps.unwrap_or(self.refine_steps), ..self.clone() }
    }
}

/// One input photo.
pub struct InputImage {
    pub name: String,
    pub bytes: Vec<u8>,
}

/// What one view looks like after reconstruction, at the model resolution.
pub struct ViewResult {
    pub camera: Camera,
    /// How [`ViewResult::camera`]'s pose was found.
    pub placement: Placement,
    /// Where its focal length came from.
    pub focal: FocalSource,
    /// How well registration fit it, in model pixels (`None` where it did not run).
    pub fit: Option<CameraFit>,
    pub letterbox: Letterbox,
    /// `[H][W]` instance id, 0 = none.
    pub instance_ids: Vec<u32>,
    /// `[H][W]` 1 + the index in [`Reconstruction::scene`] of the Gaussian this pixel's own
    /// Gaussian was merged into; 0 where the pixel made none or it was dropped.
    pub gaussians: Vec<u32>,
    /// `[H][W]` vocabulary index, `NO_LABEL` where none.
    pub labels: Vec<u32>,
    /// `[H][W]` predicted depth in metres.
    pub depth: Vec<f32>,
    /// `[H][W][3]` the letterboxed input, 8-bit.
    pub rgb: Vec<u8>,
    /// The instance and label maps at the photo's resolution ([`PipelineConfig::mask_size`]);
    /// `None` when none was asked.
    pub photo_maps: Option<PhotoMaps>,
}

/// A view's instance and label maps at its photo's resolution (up to the mask size), without
/// the letterbox.
#[derive(Debug, Clone)]
pub struct PhotoMaps {
    pub width: u32,
    pub height: u32,
    /// `[H][W]` instance id, 0 = none.
    pub instance_ids: Vec<u32>,
    /// `[H][W]` vocabulary index, `NO_LABEL` where none.
    pub labels: Vec<u32>,
}

/// A reconstructed scene.
pub struct Reconstruction {
    pub scene: GaussianScene,
    pub views: Vec<ViewResult>,
    pub instances: Vec<InstanceOut>,
    pub prototypes: Vec<InstancePrototype>,
    /// The semantic prototypes as the features gave them, before the shape classifier moved
    /// them toward its labels (what a semantic classifier reads).
    pub unfused_prototypes: Vec<InstancePrototype>,
    /// Each instance's shape descriptor (ids with too few Gaussians left out).
    pub descriptors: Vec<(u32, [f32; DESCRIPTOR.len()])>,
    pub vocabulary: Vec<String>,
    /// Φ_sem of the network: weight `[384][d_s]` and bias `[384]`.
    pub sem_proj_weight: Vec<f32>,
    pub sem_proj_bias: Vec<f32>,
    pub voxel: VoxelReport,
    pub timings: Vec<StageTiming>,
    /// What the test-time refinement did (`None` without one).
    pub refinement: Option<SceneRefinement>,
}

/// Runs the whole pipeline on `images` with the label `vocabulary`.
pub fn reconstruct(
    backend: &mut dyn Backend,
    labels: &LabelCache,
    images: &[InputImage],
    vocabulary: &[String],
    config: &PipelineConfig,
) -> Result<Reconstruction, PipelineError> {
    reconstruct_with(backend, labels, images, vocabulary, config, &|_| {})
}

/// [`reconstruct`], calling `on_stage` with each stage's name as it starts (for progress).
pub fn reconstruct_with(
    backend: &mut dyn Backend,
    labels: &LabelCache,
    images: &[InputImage],
    vocabulary: &[String],
    config: &PipelineConfig,
    on_stage: &dyn Fn(&str),
) -> Result<Reconstruction, PipelineError> {
    if !(MIN_VIEWS..=MAX_VIEWS).contains(&images.len()) {
        return Err(PipelineError::ViewCount(images.len()));
    }
    if vocabulary.is_empty() {
        return Err(PipelineError::EmptyVocabulary);
    }
    let mut clock = Stopwatch::new(on_stage);
    let network = backend.network();
    let multiple = match (config.photo_aspect, network.size_multiple) {
        (false, _) => None,
        (true, Some(m)) => Some(m as u32),
        (true, None) => {
            return Err(PipelineError::SquareOnly { resolution: network.resolution });
        }
    };
    let sizes = Sizes {
        res: network.resolution as u32,
        multiple,
        detail: config.register.as_ref().map_or(0, |r| r.photo_size),
        mask: config.mask_size,
        detect: if config.detector.is_some() { PRESHRINK } else { 0 },
    };
    let decoded = clock.time("decode", || {
        decode_all(images.par_iter().map(|i| (i.name.as_str(), i.bytes.as_slice())), sizes)
    })?;
    let boxes = match &config.detector {
        Some(detector) => Some(clock.time("detect", || detect::run(detector, &decoded))?),
        None => None,
    };
    let mut pass = clock.time("model", || network::run(backend, &decoded, &config.known))?;
    let pixels = pass.out.height * pass.out.width;
    let segments = config.superpixels.as_ref().map(|params| {
        clock.time("superpixels", || superpixels::run(&mut pass.out, &decoded, params))
    });
    let known_poses = config.known.poses.as_deref();
    let found = cameras::run(
        &mut clock,
        &pass.out,
        &decoded,
        known_poses,
        config.register.as_ref(),
        config.matcher.as_deref(),
    )?;
    let cameras::Cameras { mut cameras, placements, focal, component, fit } = found;
    if let (Some(params), Some(component)) = (&config.heading, &component) {
        clock.time("heading", || {
            heading::run(&mut cameras, component, &pass.out, &decoded, params)
        })?;
    }
    if let Some(input) = backend.network().rays.filter(|_| known_poses.is_none() && config.ray_pass)
    {
        clock.time("rays", || rays::run(backend, input, &mut pass, &cameras, segments.as_ref()))?;
    }
    let out = &pass.out;
    let all: Vec<usize> = (0..out.views).collect();
    let per_pixel = clock.time("backproject", || backproject::run(out, &cameras, &all))?;
    let mut voxelized = clock.time("voxelize", || voxelize::run(&per_pixel, &config.voxel))?;
    clock
        .time("cluster", || cluster::run(&mut voxelized, &config.cluster, config.split.as_ref()))?;
    if let Some(segments) = segments.as_ref().filter(|_| config.vote == VoteScope::Gaussians) {
        clock.time("vote", || vote::run(&mut voxelized, &per_pixel, segments, pixels));
    }
    let id_maps =
        clock.time("masks", || masks::run(&voxelized, &per_pixel, segments.as_ref(), pixels));
    let detections = config.detector.as_deref().zip(boxes.as_ref()).map(|(detector, boxes)| {
        DetectorEvidence { detector, views: masks::view_detections(&id_maps, boxes, out) }
    });
    let inputs = LabelInputs {
        projection: SemanticProjection { weight: &out.sem_proj_weight, bias: &out.sem_proj_bias },
        cameras: &cameras,
        classifier: backend.network().shapes.as_ref(),
        shape_weight: config.shape_weight,
        labels,
        vocabulary,
        detections,
    };
    let naming = clock.time("label", || label::run(&voxelized.scene, &inputs))?;
    let label_of_id = naming.label_of_id(&voxelized.scene);
    naming.write_meta(&mut voxelized.scene, vocabulary, &backend.network().model_version);
    let refinement = match config.refine_steps {
        0 => None,
        steps => Some(clock.time("refine", || {
            // Cameras the caller gave are kept; registered ones are refined with the scene.
            refine::run(&mut voxelized.scene, &mut cameras, &decoded, steps, known_poses.is_none())
        })?),
    };
    let instances = naming.instance_table(&voxelized.scene, vocabulary);
    let parts = masks::ViewParts {
        out,
        cameras: &cameras,
        placements: &placements,
        focal: &focal,
        fit: fit.as_deref(),
        voxelized: &voxelized,
        per_pixel: &per_pixel,
        label_of_id: &label_of_id,
    };
    let photo_maps = clock.time("upsample", || masks::photo_maps(&decoded, &id_maps, &label_of_id));
    let views = masks::views(decoded, id_maps, photo_maps, &parts);
    voxelized.scene.meta.producer = format!("inssplat {}", env!("CARGO_PKG_VERSION"));
    Ok(Reconstruction {
        scene: voxelized.scene,
        views,
        instances,
        prototypes: naming.prototypes,
        unfused_prototypes: naming.unfused,
        descriptors: naming.descriptors,
        vocabulary: vocabulary.to_vec(),
        sem_proj_weight: pass.out.sem_proj_weight.clone(),
        sem_proj_bias: pass.out.sem_proj_bias.clone(),
        voxel: voxelized.report,
        timings: clock.timings,
        refinement,
    })
}

/// Largest instance id of an instance table (0 when it is empty): the channel count of
/// `render_instance_ids`.
pub fn max_instance_id(instances: &[InstanceOut]) -> usize {
    instances.iter().map(|i| i.id as usize).max().unwrap_or(0)
}

/// Vocabulary index of each instance's label at index id − 1, as `label_map` takes it (`None`
/// for a label outside the vocabulary, such as "unknown").
pub fn label_table(instances: &[InstanceOut], vocabulary: &[String]) -> Vec<Option<usize>> {
    let mut table = vec![None; max_instance_id(instances)];
    for i in instances {
        table[i.id as usize - 1] = vocabulary.iter().position(|v| *v == i.label);
    }
    table
}

/// Each prototype's own-label score (its instance's `score`), as `query` takes it.
pub fn own_label_scores(prototypes: &[InstancePrototype], instances: &[InstanceOut]) -> Vec<f32> {
    prototypes
        .iter()
        .map(|p| instances.iter().find(|i| i.id == p.id).map_or(f32::MIN, |i| i.score))
        .collect()
}
