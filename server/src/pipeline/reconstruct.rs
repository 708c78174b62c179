//! The reconstruct pipeline: photos → decode (parallel) → network → instance embeddings
//! snapped to each photo's colour superpixels → register → the views no match links turned
//! to the heading where the linked views' Gaussians match their photos → back-project →
//! voxelize → cluster once in 3D → each merged Gaussian given the id most of its pixels carry
//! once every superpixel of an input view took its pixels' majority id → semantic
//! prototypes, moved toward what the shape classifier makes of each instance's size and
//! colour → text labels → (optionally) the Gaussians and cameras
//! refined against the photos, ids and names kept → per-view instance and label maps. An
//! input view's maps need no rendering: each pixel's own Gaussian was merged into one clustered
//! Gaussian, whose id it takes (exact at the pixel's own surface, and the same id in every
//! view that sees that Gaussian), and then each superpixel takes its pixels' majority id;
//! novel views are rendered (`inssplat render`, eval's target views). Every stage is timed.

use std::time::Instant;

use glam::{Quat, Vec2, Vec3};
use inssplat_proto::api::{FocalSource, InstanceOut, Placement, StageTiming};
use inssplat_proto::shape::{DESCRIPTOR, label_cosines};
use inssplat_proto::signature::{CAMERA_CHANNELS, GAUSSIAN_CHANNELS, MAX_VIEWS, MIN_VIEWS};
use inssplat_proto::rays::{median_depth, patch_rays};
use inssplat_proto::{Camera, GaussianScene, INSTANCE_DIM, Intrinsics};
use inssplat_raster::backproject::{BackProjected, ViewOutputs, backproject};
use inssplat_raster::heading::{HeadingParams, place_by_heading};
use inssplat_raster::cluster::split::{SplitParams, split_disconnected};
use inssplat_raster::cluster::{ClusterError, ClusterParams, cluster_instances};
use inssplat_raster::superpixel::{SuperpixelParams, segment, snap, vote};
use inssplat_raster::label::masks::label_map;
use inssplat_raster::refine::{RefineParams, RefineView, SceneRefinement, refine_scene};
use inssplat_raster::register::{Descriptors, KeypointImage, RegisterParams, RegisterView, register};
use inssplat_raster::label::shape::{fuse, instance_descriptors};
use inssplat_raster::label::{InstancePrototype, SemanticProjection, assign_labels, semantic_prototypes};
use inssplat_raster::voxel::{DROPPED, VoxelParams, VoxelReport, Voxelized, voxelize};
use inssplat_text::LabelCache;
use rayon::prelude::*;

use super::decode::{DecodeError, Letterbox, decode};
use crate::runtime::{Model, ModelOutput, RuntimeError};

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error("{0} images given; inssplat needs between {MIN_VIEWS} and {MAX_VIEWS} views of one scene")]
    ViewCount(usize),
    #[error(transparent)]
    Decode(#[from] DecodeError),
    #[error(transparent)]
    Runtime(#[from] RuntimeError),
    #[error("label vocabulary is empty")]
    EmptyVocabulary,
    #[error("{given} known camera poses for {views} views; give one per view, in order")]
    Poses { given: usize, views: usize },
    #[error("{given} known depth values for {views} views of {pixels} pixels; give one per pixel of every view at the model resolution")]
    Depth { given: usize, views: usize, pixels: usize },
    #[error("this network reads its cameras as rays: known camera poses need the scene's median depth in their units beside them")]
    RaysNeedScale,
    #[error("{stage}: {message}")]
    Stage { stage: &'static str, message: String },
}

fn stage_err(stage: &'static str) -> impl Fn(&dyn std::fmt::Display) -> PipelineError {
    move |e| PipelineError::Stage { stage, message: e.to_string() }
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
    /// Register the views from matched keypoints (and the network's learned descriptors when
    /// it outputs them) and the predicted depth (the "register"
    /// stage; views it cannot reach keep the camera head's pose). `None`: the camera head's
    /// poses as they are.
    pub register: Option<RegisterParams>,
    /// Known cameras of the inputs, in order (world→camera in any metric frame, intrinsics at
    /// the model resolution), used instead of the network's camera head; the network's depth,
    /// Gaussians and features are placed with them. `None`: the predicted cameras.
    pub known_poses: Option<Vec<Camera>>,
    /// Known depth of the inputs, `[V][H][W]` metres at the model resolution (0: no surface,
    /// that pixel keeps the depth head's value), used instead of the depth head wherever the
    /// depth is read (registration, back-projection); the network's per-pixel offsets,
    /// Gaussians and features are kept. `None`: the predicted depth.
    pub known_depth: Option<Vec<f32>>,
    /// The median depth of the input views in the units of [`PipelineConfig::known_poses`],
    /// which a network that reads its cameras as rays ([`crate::runtime::RayInput`]) needs
    /// with them (it divides the camera centres).
    pub known_median_depth: Option<f32>,
    /// With a network that reads its cameras as rays and no known poses: run it a second
    /// time on the rays of the registered cameras (stage "rays") and take its instance and
    /// semantic features from that pass; `false`: its first pass, with every ray zero, is all.
    pub ray_pass: bool,
    /// Weight of the shape classifier's text-space direction added to each instance's
    /// semantic prototype before naming (0, or a model without a classifier, names by the
    /// semantic features alone).
    pub shape_weight: f32,
    /// Adam steps of test-time refinement of the Gaussians and the input cameras (not
    /// [`PipelineConfig::known_poses`]) against the input photos after the instances are
    /// clustered and named, which it keeps (stage "refine", [`inssplat_raster::refine`]; 0, the
    /// default, is the feed-forward pipeline).
    pub refine_steps: usize,
    /// Snap each view's instance embeddings to its photo's colour superpixels before they
    /// are placed, and give every superpixel of an input view's instance map the id most of
    /// its pixels carry (stage "superpixels", [`inssplat_raster::superpixel`]; `None`: the
    /// network's maps as they are, and each pixel its own merged Gaussian's id).
    pub superpixels: Option<SuperpixelParams>,
    /// Turn each component of views that registration could not link to the first photo to
    /// the heading at which the linked views' Gaussians match its photos best (stage
    /// "heading", [`inssplat_raster::heading`]; `None`: the continued poses stay).
    pub heading: Option<HeadingParams>,
    /// What the superpixel vote corrects (with [`PipelineConfig::superpixels`] only).
    pub vote: VoteScope,
}

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
            known_poses: None,
            known_depth: None,
            known_median_depth: None,
            ray_pass: true,
            shape_weight: DEFAULT_SHAPE_WEIGHT,
            refine_steps: 0,
            superpixels: Some(SuperpixelParams::default()),
            heading: Some(HeadingParams::default()),
            vote: VoteScope::Gaussians,
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
    /// Where every view's focal length came from.
    pub focal: FocalSource,
    /// What the test-time refinement did (`None` without one).
    pub refinement: Option<SceneRefinement>,
}

/// Collects stage timings and tells an observer when each stage starts.
struct Stopwatch<'a> {
    timings: Vec<StageTiming>,
    on_stage: &'a dyn Fn(&str),
}

impl Stopwatch<'_> {
    fn time<T>(&mut self, stage: &str, f: impl FnOnce() -> T) -> T {
        (self.on_stage)(stage);
        let start = Instant::now();
        let out = f();
        self.timings.push(StageTiming { stage: stage.to_string(), ms: start.elapsed().as_secs_f64() * 1e3 });
        out
    }
}

/// Cameras predicted by the network (model resolution, world = view 0's camera).
pub fn predicted_cameras(out: &ModelOutput) -> Vec<Camera> {
    out.camera
        .chunks_exact(CAMERA_CHANNELS)
        .map(|c| {
            let q = Quat::from_xyzw(c[4], c[5], c[6], c[3]);
            let rotation = if q.is_finite() && q.length() > 1e-8 { q.normalize() } else { Quat::IDENTITY };
            let focal = |fov: f32, size: usize| 0.5 * size as f32 / (0.5 * fov.clamp(0.05, 3.0)).tan();
            let intrinsics = Intrinsics {
                fx: focal(c[8], out.width),
                fy: focal(c[7], out.height),
                cx: 0.5 * out.width as f32,
                cy: 0.5 * out.height as f32,
                width: out.width as u32,
                height: out.height as u32,
            };
            Camera { intrinsics, rotation, translation: Vec3::new(c[0], c[1], c[2]) }
        })
        .collect()
}

/// How registration placed view `v`, given the root of its component
/// ([`inssplat_raster::register::Registration::component`]).
fn placement(v: usize, root: usize) -> Placement {
    match (v, root) {
        (0, _) => Placement::Reference,
        (_, 0) => Placement::Registered,
        (_, 1) => Placement::CameraHead,
        _ => Placement::Continued,
    }
}

/// Runs the whole pipeline on `images` with the label `vocabulary`.
pub fn reconstruct(
    model: &mut Model,
    labels: &LabelCache,
    images: &[InputImage],
    vocabulary: &[String],
    config: &PipelineConfig,
) -> Result<Reconstruction, PipelineError> {
    reconstruct_with(model, labels, images, vocabulary, config, &|_| {})
}

/// [`reconstruct`], calling `on_stage` with each stage's name as it starts (for progress).
pub fn reconstruct_with(
    model: &mut Model,
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
    let mut clock = Stopwatch { timings: Vec::new(), on_stage };
    let res = model.resolution;
    let decoded = clock.time("decode", || {
        let detail = config.register.as_ref().map_or(0, |r| r.photo_size);
        images.par_iter().map(|i| decode(&i.name, &i.bytes, res as u32, detail)).collect::<Result<Vec<_>, _>>()
    })?;
    let batch: Vec<f32> = decoded.iter().flat_map(|d| d.planar.iter().copied()).collect();
    // A network that reads rays gets the known cameras', else none (zero) before registration.
    let rays = match (model.rays, &config.known_poses, config.known_median_depth) {
        (None, _, _) => None,
        (Some(input), None, _) => Some(vec![0.0; input.values(images.len())]),
        (Some(input), Some(poses), Some(scale)) if scale > 0.0 => Some(patch_rays(poses, res, input.patch(res), input.k, scale)),
        (Some(_), Some(_), _) => return Err(PipelineError::RaysNeedScale),
    };
    let mut out = clock.time("model", || model.run(&batch, images.len(), rays.as_deref()))?;
    let pixels = out.height * out.width;
    if let Some(known) = &config.known_depth {
        if known.len() != out.depth.len() {
            return Err(PipelineError::Depth { given: known.len(), views: out.views, pixels });
        }
        for (d, &k) in out.depth.iter_mut().zip(known) {
            if k > 0.0 {
                *d = k;
            }
        }
    }
    let plane = |channels: usize, v: usize| v * channels * pixels..(v + 1) * channels * pixels;
    let segments: Option<Vec<Vec<u32>>> = config.superpixels.as_ref().map(|params| {
        clock.time("superpixels", || {
            let (width, height) = (out.width, out.height);
            out.instance
                .par_chunks_exact_mut(INSTANCE_DIM * pixels)
                .zip(&decoded)
                .map(|(map, d)| {
                    let segments = segment(&d.planar, width, height, params);
                    snap(map, &segments);
                    segments
                })
                .collect()
        })
    });
    let head = |views: usize| (0..views).map(|v| if v == 0 { Placement::Reference } else { Placement::CameraHead }).collect();
    let (mut cameras, placements, focal, component): (Vec<Camera>, Vec<Placement>, FocalSource, Option<Vec<usize>>) = match &config.known_poses {
        None => {
            let predicted = predicted_cameras(&out);
            match &config.register {
                None => (predicted, head(out.views), FocalSource::CameraHead, None),
                Some(params) => clock.time("register", || {
                    let details: Vec<Option<KeypointImage>> = decoded
                        .iter()
                        .map(|d| d.detail_in_model().map(|(rgb, per_view, [x, y])| KeypointImage::of_photo(rgb, per_view, Vec2::new(x, y))))
                        .collect();
                    let views: Vec<RegisterView<'_>> = (0..out.views)
                        .map(|v| RegisterView {
                            rgb: &decoded[v].planar,
                            depth: &out.depth[plane(1, v)],
                            photo: decoded[v].letterbox.photo_rect(),
                            camera: &predicted[v],
                            descriptors: out.descriptors.as_ref().map(|(data, dim)| Descriptors { data: &data[plane(*dim, v)], dim: *dim }),
                            detail: details[v].as_ref(),
                        })
                        .collect();
                    let registration = register(&views, params);
                    let placements = registration.component.iter().enumerate().map(|(v, &root)| placement(v, root)).collect();
                    let focal = if registration.focal_scale.is_some() { FocalSource::Measured } else { FocalSource::CameraHead };
                    (registration.cameras, placements, focal, Some(registration.component))
                }),
            }
        }
        Some(poses) if poses.len() == images.len() => (poses.clone(), vec![Placement::Given; poses.len()], FocalSource::Given, None),
        Some(poses) => return Err(PipelineError::Poses { given: poses.len(), views: images.len() }),
    };

    let outputs = |out: &ModelOutput, cameras: &[Camera], views: &[usize]| -> Result<BackProjected, PipelineError> {
        let views: Vec<ViewOutputs<'_>> = views
            .iter()
            .map(|&v| ViewOutputs {
                camera: &cameras[v],
                depth: &out.depth[plane(1, v)],
                depth_conf: &out.depth_conf[plane(1, v)],
                gaussians: &out.gaussians[plane(GAUSSIAN_CHANNELS, v)],
                instance: &out.instance[plane(INSTANCE_DIM, v)],
                semantic: &out.semantic[plane(out.sem_dim, v)],
            })
            .collect();
        backproject(&views, out.sem_dim).map_err(|e| stage_err("backproject")(&e))
    };
    if let (Some(params), Some(component)) = (&config.heading, &component) {
        clock.time("heading", || -> Result<(), PipelineError> {
            let photos: Vec<&[f32]> = decoded.iter().map(|d| d.planar.as_slice()).collect();
            let depths: Vec<&[f32]> = (0..out.views).map(|v| &out.depth[plane(1, v)]).collect();
            // Every `factor`-th pixel's Gaussian, grown to cover as many, for the renders at
            // 1/`factor` of the size: a tenth of the cost of all of them (val40, 8 views). A
            // back-projection error is named by the stage "backproject" right after.
            let stride = params.factor as u32;
            let gaussians = |cameras: &[Camera], views: &[usize]| {
                outputs(&out, cameras, views).map_or_else(|_| GaussianScene::with_sem_dim(0), |b| b.thinned(out.width as u32, out.height as u32, stride))
            };
            place_by_heading(&mut cameras, component, &photos, &depths, params, &gaussians).map_err(|e| stage_err("heading")(&e))?;
            Ok(())
        })?;
    }
    if let Some(input) = model.rays.filter(|_| config.known_poses.is_none() && config.ray_pass) {
        clock.time("rays", || -> Result<(), PipelineError> {
            // The registered cameras are in the depth's units, as the true ones are in the
            // true depth's when the network learns.
            let scale = median_depth(&out.depth).unwrap_or(1.0);
            let second = model.run(&batch, out.views, Some(&patch_rays(&cameras, res, input.patch(res), input.k, scale)))?;
            out.instance = second.instance;
            out.semantic = second.semantic;
            if let Some(segments) = &segments {
                out.instance.par_chunks_exact_mut(INSTANCE_DIM * pixels).zip(segments).for_each(|(map, s)| snap(map, s));
            }
            Ok(())
        })?;
    }
    let per_pixel = clock.time("backproject", || outputs(&out, &cameras, &(0..out.views).collect::<Vec<_>>()));
    let per_pixel = per_pixel?;
    let mut voxelized =
        clock.time("voxelize", || voxelize(&per_pixel.scene, &config.voxel)).map_err(|e| stage_err("voxelize")(&e))?;
    clock
        .time("cluster", || {
            cluster_instances(&mut voxelized.scene, &config.cluster)?;
            if let Some(split) = &config.split {
                let cell = split.cell_voxels * voxelized.report.voxel_size;
                split_disconnected(&voxelized.scene.means, &mut voxelized.scene.instance_id, cell, split);
            }
            Ok::<_, ClusterError>(())
        })
        .map_err(|e| stage_err("cluster")(&e))?;
    // Each input view's mask read from the merged Gaussians, every superpixel given the id
    // most of its pixels carry, so that the masks follow the photo's edges where merged
    // Gaussians of two instances meet.
    let voted_maps = |voxelized: &Voxelized| -> Vec<u32> {
        let mut maps = per_pixel.to_pixels(&voxelized.input_instance_ids());
        if let Some(segments) = &segments {
            maps.chunks_exact_mut(pixels).zip(segments).for_each(|(ids, s)| vote(ids, s));
        }
        maps
    };
    if segments.is_some() && config.vote == VoteScope::Gaussians {
        clock.time("vote", || {
            let maps = voted_maps(&voxelized);
            let input_ids: Vec<u32> = per_pixel.pixel.iter().map(|&p| maps[p as usize]).collect();
            voxelized.adopt_member_majority(&input_ids);
        });
    }
    let scene = &mut voxelized.scene;

    let projection = SemanticProjection { weight: &out.sem_proj_weight, bias: &out.sem_proj_bias };
    let (prototypes, unfused_prototypes, matches, descriptors) = clock.time("label", || -> Result<_, PipelineError> {
        let err = stage_err("label");
        let mut prototypes = semantic_prototypes(scene, &projection).map_err(|e| err(&e))?;
        let unfused = prototypes.clone();
        let (_, descriptors) = instance_descriptors(scene, &cameras);
        if let Some(classifier) = model.shapes.as_ref().filter(|_| config.shape_weight > 0.0) {
            let names: Vec<&str> = classifier.labels.iter().map(String::as_str).collect();
            let texts = labels.embed(&names).map_err(|e| err(&e))?;
            let probabilities: Vec<(u32, Vec<f32>)> = descriptors
                .iter()
                .filter_map(|(id, d)| {
                    let cosines = match classifier.semantic {
                        true => label_cosines(&prototypes.iter().find(|p| p.id == *id)?.embedding, &texts),
                        false => Vec::new(),
                    };
                    Some((*id, classifier.probabilities(d, &cosines)))
                })
                .collect();
            fuse(&mut prototypes, &probabilities, &texts, config.shape_weight);
        }
        let words: Vec<&str> = vocabulary.iter().map(String::as_str).collect();
        let texts = labels.embed(&words).map_err(|e| err(&e))?;
        let matches = assign_labels(&prototypes, &texts).map_err(|e| err(&e))?;
        Ok((prototypes, unfused, matches, descriptors))
    })?;
    let k = scene.instance_id.iter().copied().max().unwrap_or(0) as usize;
    let mut label_of_id = vec![None; k];
    for (p, m) in prototypes.iter().zip(&matches) {
        label_of_id[p.id as usize - 1] = m.map(|m| m.label);
    }
    scene.meta.labels = prototypes
        .iter()
        .zip(&matches)
        .filter_map(|(p, m)| m.map(|m| (p.id, vocabulary[m.label].clone())))
        .collect();
    scene.meta.model_version = Some(model.model_version.clone());
    scene.meta.up_axis = Some("-y".into());
    let refinement = match config.refine_steps {
        0 => None,
        steps => Some(
            clock
                .time("refine", || {
                    let views: Vec<RefineView<'_>> =
                        decoded.iter().map(|d| RefineView { photo: &d.planar, rect: d.letterbox.photo_rect() }).collect();
                    // Cameras the caller gave are kept; registered ones are refined with the scene.
                    let params = RefineParams { steps, cameras: config.known_poses.is_none() };
                    refine_scene(scene, &mut cameras, &views, params)
                })
                .map_err(|e| stage_err("refine")(&e))?,
        ),
    };
    let instances = instance_table(scene, &prototypes, &matches, vocabulary);

    let id_maps: Vec<Vec<u32>> = clock.time("masks", || voted_maps(&voxelized).chunks_exact(pixels).map(<[u32]>::to_vec).collect());
    let merged_into: Vec<u32> = voxelized.voxel_of.iter().map(|&v| if v == DROPPED { 0 } else { v + 1 }).collect();
    let gaussian_maps = per_pixel.to_pixels(&merged_into);
    let views = decoded
        .into_iter()
        .zip(id_maps)
        .zip(gaussian_maps.chunks_exact(pixels))
        .enumerate()
        .map(|(v, ((d, ids), gaussians))| ViewResult {
            camera: cameras[v],
            placement: placements[v],
            letterbox: d.letterbox,
            labels: label_map(&ids, &label_of_id),
            instance_ids: ids,
            gaussians: gaussians.to_vec(),
            depth: out.depth[plane(1, v)].to_vec(),
            rgb: (0..pixels).flat_map(|p| [0, 1, 2].map(|c| (d.planar[c * pixels + p] * 255.0).round() as u8)).collect(),
        })
        .collect();
    voxelized.scene.meta.producer = format!("inssplat {}", env!("CARGO_PKG_VERSION"));
    Ok(Reconstruction {
        scene: voxelized.scene,
        views,
        instances,
        prototypes,
        unfused_prototypes,
        descriptors,
        vocabulary: vocabulary.to_vec(),
        sem_proj_weight: out.sem_proj_weight.clone(),
        sem_proj_bias: out.sem_proj_bias.clone(),
        voxel: voxelized.report,
        timings: clock.timings,
        focal,
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
    prototypes.iter().map(|p| instances.iter().find(|i| i.id == p.id).map_or(f32::MIN, |i| i.score)).collect()
}

/// Id, label, score, Gaussian count and bounding box of every instance.
fn instance_table(
    scene: &GaussianScene,
    prototypes: &[InstancePrototype],
    matches: &[Option<inssplat_raster::label::LabelMatch>],
    vocabulary: &[String],
) -> Vec<InstanceOut> {
    prototypes
        .iter()
        .zip(matches)
        .map(|(p, m)| {
            let mut bbox = [[f32::INFINITY; 3], [f32::NEG_INFINITY; 3]];
            for (mean, _) in scene.means.iter().zip(&scene.instance_id).filter(|(_, id)| **id == p.id) {
                for a in 0..3 {
                    bbox[0][a] = bbox[0][a].min(mean[a]);
                    bbox[1][a] = bbox[1][a].max(mean[a]);
                }
            }
            InstanceOut {
                id: p.id,
                label: m.map_or_else(|| "unknown".to_string(), |m| vocabulary[m.label].clone()),
                score: m.map_or(0.0, |m| m.score),
                gaussians: p.gaussians,
                bbox,
            }
        })
        .collect()
}
