//! Training samples: which scene and which views each step sees, read from a folder of scenes
//! in the docs/DATASET.md format or synthesized on the fly, and turned into host arrays the step
//! feeds to the network and the losses.
//!
//! A sample is a pure function of (seed, index i): the scene is `first_scene + i / reuse` (a
//! scene serves `reuse` consecutive samples with different views), the view count and the
//! views come from a ChaCha RNG seeded with the seed and i; a run of k samples per step gives
//! step s samples s·k .. s·k + k. Resuming at step s therefore sees exactly the data an
//! uninterrupted run would have seen. [`Prefetcher`] builds the samples of the coming steps on
//! background threads, so data never stalls the step.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

use inssplat_proto::Camera;
use inssplat_proto::dataset::Scene;
use inssplat_proto::signature::TEXT_DIM;
use inssplat_text::LabelCache;
use rand::seq::index::sample as sample_indices;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::loss::camera_targets;
use inssplat_synth::stats::SHELL_LABELS;
use inssplat_synth::{self as synth, Furniture, Split, Structure, SynthConfig};

/// Where scenes come from. Serialized into checkpoints so that `--resume` reads the same data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum DataSpec {
    /// Scene folders (each with a `transforms.json`) directly inside this folder.
    Folder(PathBuf),
    /// Scenes of a split generated on demand; `furniture_dir` `None` = primitives only.
    /// `structure` says whether walls, floor and ceiling are instances with labels (so the
    /// network learns to name and separate them) or unlabelled background. `antialias` is
    /// [`SynthConfig::antialias`] (runs saved before it existed read 1).
    Synth {
        split: Split,
        furniture_dir: Option<PathBuf>,
        size: u32,
        structure: Structure,
        #[serde(default = "one_ray")]
        antialias: u32,
    },
}

fn one_ray() -> u32 {
    1
}

/// Why samples cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum SampleError {
    #[error("--data {dir}: {problem}")]
    Folder { dir: PathBuf, problem: String },
    #[error(transparent)]
    Dataset(#[from] inssplat_proto::dataset::DatasetError),
    #[error(transparent)]
    Synth(#[from] synth::SynthError),
    #[error("scene {scene}: {problem}")]
    Scene { scene: String, problem: String },
    #[error("semantic teacher: {0}")]
    Text(#[from] inssplat_text::TextError),
}

/// An opened [`DataSpec`].
#[derive(Debug, Clone)]
pub enum Source {
    Folder(Arc<Vec<PathBuf>>),
    Synth(Arc<SynthConfig>),
}

impl Source {
    /// Opens `spec`: lists the scene folders (an error names the folder if there are none) or
    /// checks the synthesis configuration.
    pub fn open(spec: &DataSpec) -> Result<Self, SampleError> {
        match spec {
            DataSpec::Folder(dir) => {
                let problem = |problem: String| SampleError::Folder { dir: dir.clone(), problem };
                let entries = std::fs::read_dir(dir)
                    .map_err(|e| problem(format!("cannot read the folder: {e}")))?;
                let mut scenes: Vec<PathBuf> = entries
                    .filter_map(|e| e.ok().map(|e| e.path()))
                    .filter(|p| p.join("transforms.json").is_file())
                    .collect();
                if scenes.is_empty() {
                    return Err(problem(
                        "no scene folders (sub-folders with a transforms.json) in it".into(),
                    ));
                }
                scenes.sort();
                Ok(Source::Folder(Arc::new(scenes)))
            }
            DataSpec::Synth { split, furniture_dir, size, structure, antialias } => {
                let furniture = match furniture_dir {
                    Some(dir) => Furniture::Catalog(dir.clone()),
                    None => Furniture::Primitives,
                };
                let mut cfg = SynthConfig::new(*split, furniture);
                cfg.width = *size;
                cfg.height = *size;
                cfg.structure = *structure;
                cfg.antialias = *antialias;
                cfg.validate()?;
                Ok(Source::Synth(Arc::new(cfg)))
            }
        }
    }

    /// Scene number `index` (folders wrap around).
    pub fn scene(&self, index: u64) -> Result<Scene, SampleError> {
        match self {
            Source::Folder(paths) => Ok(Scene::load(wrapped(paths, index))?),
            Source::Synth(cfg) => Ok(synth::generate_split(index, cfg)?.scene),
        }
    }
}

/// The folder of scene number `index` among `paths`, wrapping around.
fn wrapped(paths: &[PathBuf], index: u64) -> &Path {
    &paths[(index % paths.len() as u64) as usize]
}

/// How views are drawn for a step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ViewPlan {
    /// Input views per step, drawn uniformly in `min..=max`.
    pub min_views: usize,
    pub max_views: usize,
    /// Extra views rendered from the inputs' Gaussians and supervised, but never input.
    pub targets: usize,
    /// Consecutive samples that share one scene.
    pub reuse: u64,
    /// The scene of sample 0.
    pub first_scene: u64,
    /// Draw a step's views from this many consecutive frames of the trajectory (at a random
    /// start; at least as many as the step's views), so that they overlap; `None` (also what
    /// plans saved before this existed read as): from the whole trajectory.
    #[serde(default)]
    pub window: Option<usize>,
}

/// One step's data on the host. Views `0..inputs` are the network's input; the rest are
/// render-only targets. All per-view arrays are view-major, `[V][..][H][W]`.
#[derive(Debug, Clone)]
pub struct Sample {
    /// Where the views come from, for messages.
    pub scene: String,
    pub inputs: usize,
    pub size: usize,
    /// `[V, 3, H, W]` RGB in [0, 1].
    pub images: Vec<f32>,
    /// `[V][H][W]` metric depth, 0 = no surface.
    pub depth: Vec<f32>,
    /// `[V][H][W]` instance ids, 0 = background.
    pub ids: Vec<u32>,
    /// Ground-truth cameras with view 0 as the world frame (as the network predicts them).
    pub cameras: Vec<Camera>,
    /// `[rows, 384]`: row `id` is the MiniLM embedding of instance `id`'s label (row 0 zero).
    pub teacher: Vec<f32>,
    /// `[K, 384]`: the embeddings of every label the synthesizer can produce, the classes of
    /// the contrastive L_sem.
    pub vocabulary: Vec<f32>,
    /// Instance ids labelled as the room's shell (`wall`, `floor`, `ceiling`).
    pub shell: Vec<u32>,
    /// The input views' cameras that a network trained with `--camera-rays` reads
    /// ([`super::ray_dropout`]).
    pub ray_cameras: RayCameras,
}

/// The cameras a network that reads them gets as rays.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum RayCameras {
    /// The true ones, [`Sample::cameras`].
    #[default]
    True,
    /// None: every ray zero, the network's input before registration.
    Dropped,
}

impl Sample {
    /// Number of views (inputs and targets).
    pub fn views(&self) -> usize {
        self.cameras.len()
    }

    /// Rows of the teacher table.
    pub fn teacher_rows(&self) -> usize {
        self.teacher.len() / TEXT_DIM
    }

    /// The sample of `scene` for the views `order` (the first `inputs` of them are input).
    pub fn from_scene(
        scene: &Scene,
        order: &[usize],
        inputs: usize,
        labels: &LabelCache,
    ) -> Result<Self, SampleError> {
        let name = scene.dir.display().to_string();
        let bad = |problem: String| SampleError::Scene { scene: name.clone(), problem };
        let first = scene.frames.first().ok_or_else(|| bad("has no frames".into()))?;
        let (w, h) = (first.width() as usize, first.height() as usize);
        if let Some(f) = scene
            .frames
            .iter()
            .position(|f| f.width() != first.width() || f.height() != first.height())
        {
            return Err(bad(format!("frame {f} differs in size from frame 0")));
        }
        if w != h {
            return Err(bad(format!("frames are {w}×{h}; training needs square frames")));
        }
        let pixels = w * h;
        let mut images = Vec::with_capacity(order.len() * 3 * pixels);
        let mut depth = Vec::with_capacity(order.len() * pixels);
        let mut ids = Vec::with_capacity(order.len() * pixels);
        let mut cameras = Vec::with_capacity(order.len());
        for &f in order {
            let frame = &scene.frames[f];
            images.extend(frame.planar_rgb());
            let frame_depth =
                frame.depth.as_ref().ok_or_else(|| bad(format!("frame {f} has no depth")))?;
            depth.extend_from_slice(frame_depth);
            let frame_ids = frame
                .instances
                .as_ref()
                .ok_or_else(|| bad(format!("frame {f} has no instance map")))?;
            ids.extend(frame_ids.iter().map(|&i| u32::from(i)));
            cameras.push(frame.camera);
        }
        let cameras = in_reference_frame(&cameras);
        let rows = ids.iter().copied().max().unwrap_or(0) as usize + 1;
        let mut teacher = vec![0.0; rows * TEXT_DIM];
        let present: Vec<(u32, &str)> =
            (1..rows as u32).filter_map(|id| scene.label_of(id as u16).map(|l| (id, l))).collect();
        let embeddings = labels.embed(&present.iter().map(|(_, l)| *l).collect::<Vec<_>>())?;
        for ((id, _), e) in present.iter().zip(embeddings) {
            teacher[*id as usize * TEXT_DIM..(*id as usize + 1) * TEXT_DIM].copy_from_slice(&e);
        }
        let all: Vec<&str> = inssplat_synth::all_labels().into_iter().collect();
        let vocabulary = labels.embed(&all)?.iter().flatten().copied().collect();
        let shell =
            present.iter().filter(|(_, l)| SHELL_LABELS.contains(l)).map(|(id, _)| *id).collect();
        Ok(Sample {
            scene: name,
            inputs,
            size: w,
            images,
            depth,
            ids,
            cameras,
            teacher,
            vocabulary,
            shell,
            ray_cameras: RayCameras::True,
        })
    }
}

/// `cameras` re-expressed with the first one as the world frame.
pub fn in_reference_frame(cameras: &[Camera]) -> Vec<Camera> {
    camera_targets(cameras)
        .iter()
        .zip(cameras)
        .map(|(t, cam)| Camera {
            intrinsics: cam.intrinsics,
            rotation: glam::Quat::from_xyzw(t[4], t[5], t[6], t[3]),
            translation: glam::Vec3::new(t[0], t[1], t[2]),
        })
        .collect()
}

/// Draws the views of one step: `inputs + targets` distinct frames of `frames` (of a random
/// window of [`ViewPlan::window`] consecutive ones, if set), in random order (the first is the
/// reference view). Fewer frames than asked shrink the targets first.
pub fn draw_views(frames: usize, plan: &ViewPlan, rng: &mut ChaCha8Rng) -> (Vec<usize>, usize) {
    let inputs = rng.random_range(plan.min_views..=plan.max_views).min(frames);
    let total = (inputs + plan.targets).min(frames);
    let Some(window) = plan.window else {
        return (sample_indices(rng, frames, total).into_vec(), inputs);
    };
    let span = window.max(total).min(frames);
    let start = rng.random_range(0..=frames - span);
    (sample_indices(rng, span, total).into_iter().map(|i| start + i).collect(), inputs)
}

/// Makes the samples of steps: scene choice and view draws as described in the module docs.
#[derive(Clone)]
pub struct Sampler {
    pub source: Source,
    pub plan: ViewPlan,
    pub seed: u64,
    pub labels: Arc<LabelCache>,
}

impl Sampler {
    /// The scene sample `index` draws from (with one sample per step, the step's).
    pub fn scene_index(&self, index: u64) -> u64 {
        self.plan.first_scene + index / self.plan.reuse.max(1)
    }

    /// Sample `index` of the run.
    pub fn sample(&self, index: u64) -> Result<Sample, SampleError> {
        let scene = self.source.scene(self.scene_index(index))?;
        self.sample_of(&scene, index)
    }

    /// Sample `index` drawn from `scene`.
    pub fn sample_of(&self, scene: &Scene, index: u64) -> Result<Sample, SampleError> {
        let mut rng =
            ChaCha8Rng::seed_from_u64(self.seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        if scene.frames.len() < 2 {
            return Err(SampleError::Scene {
                scene: scene.dir.display().to_string(),
                problem: "needs ≥ 2 frames".into(),
            });
        }
        let (order, inputs) = draw_views(scene.frames.len(), &self.plan, &mut rng);
        Sample::from_scene(scene, &order, inputs, &self.labels)
    }
}

/// Builds samples `start..end` (sample i of a run with k samples per step belongs to step
/// i / k) on background threads, a few ahead, and hands them out in order. Each of the
/// `workers` threads owns the scenes whose index is its own modulo their number, so a scene is
/// made once however many samples it serves, and a step that needs several scenes gets them
/// made side by side.
pub struct Prefetcher {
    sampler: Arc<Sampler>,
    receivers: Vec<Receiver<(u64, Result<Sample, SampleError>)>>,
    workers: Vec<JoinHandle<()>>,
    next: u64,
}

impl Prefetcher {
    /// Starts `workers` threads (at least one); at most `ahead` samples wait (split between them).
    pub fn start(sampler: Sampler, start: u64, end: u64, ahead: usize, workers: usize) -> Self {
        let sampler = Arc::new(sampler);
        let count = workers.max(1) as u64;
        let (mut receivers, mut handles) = (Vec::new(), Vec::new());
        for w in 0..count {
            let (sender, receiver): (SyncSender<_>, _) =
                sync_channel(ahead.div_ceil(count as usize).max(1));
            let sampler = sampler.clone();
            let worker = std::thread::Builder::new()
                .name(format!("inssplat-data-{w}"))
                .spawn(move || {
                    let mut cached: Option<(u64, Scene)> = None;
                    let owned = (start..end)
                        .map(|step| (step, sampler.scene_index(step)))
                        .filter(|(_, index)| index % count == w);
                    for (step, index) in owned {
                        let sample = match &cached {
                            Some((i, scene)) if *i == index => sampler.sample_of(scene, step),
                            _ => sampler.source.scene(index).and_then(|scene| {
                                let s = sampler.sample_of(&scene, step);
                                cached = Some((index, scene));
                                s
                            }),
                        };
                        if sender.send((step, sample)).is_err() {
                            return;
                        }
                    }
                })
                .expect("spawn a data thread");
            receivers.push(receiver);
            handles.push(worker);
        }
        Self { sampler, receivers, workers: handles, next: start }
    }
}

impl Iterator for Prefetcher {
    type Item = (u64, Result<Sample, SampleError>);

    /// The next sample with its index; `None` once `end` is reached (the thread that would own
    /// sample `end` has finished and closed its channel).
    fn next(&mut self) -> Option<Self::Item> {
        let owner = (self.sampler.scene_index(self.next) % self.receivers.len() as u64) as usize;
        let item = self.receivers[owner].recv().ok()?;
        debug_assert_eq!(item.0, self.next, "a data thread skipped a sample");
        self.next += 1;
        Some(item)
    }
}

impl Drop for Prefetcher {
    fn drop(&mut self) {
        // Unblock the workers (their sends fail once the receivers are gone) and let them finish.
        self.receivers.clear();
        for worker in self.workers.drain(..) {
            let _ = worker.join();
        }
    }
}

/// A short description of a data spec for logs.
pub fn describe(spec: &DataSpec) -> String {
    match spec {
        DataSpec::Folder(dir) => format!("scenes in {}", dir.display()),
        DataSpec::Synth { split, furniture_dir, size, structure, antialias } => format!(
            "{split} scenes synthesized on the fly at {size}²{}, room shell as {structure:?} ({})",
            if *antialias > 1 {
                format!(" ({antialias}×{antialias} rays a pixel)")
            } else {
                String::new()
            },
            furniture_dir.as_deref().map_or("primitives only".to_string(), |d: &Path| format!(
                "furniture {}",
                d.display()
            ))
        ),
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;

    use super::*;

    #[test]
    fn a_view_window_keeps_each_steps_views_among_consecutive_frames() {
        let plan = ViewPlan {
            min_views: 2,
            max_views: 8,
            targets: 1,
            reuse: 1,
            first_scene: 0,
            window: None,
        };
        let windowed = ViewPlan { window: Some(6), ..plan };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (mut spread, mut starts) = (0, std::collections::BTreeSet::new());
        for _ in 0..200 {
            let (views, inputs) = draw_views(24, &windowed, &mut rng);
            let (lo, hi) = (*views.iter().min().unwrap(), *views.iter().max().unwrap());
            assert_eq!(views.len(), (inputs + 1).min(24));
            assert_eq!(
                views.iter().collect::<std::collections::BTreeSet<_>>().len(),
                views.len(),
                "distinct: {views:?}"
            );
            // Never wider than the window, or than the step's views when they outnumber it.
            assert!(hi - lo < views.len().max(6), "{views:?}");
            starts.insert(lo);
            let (all, _) = draw_views(24, &plan, &mut rng);
            spread = spread.max(all.iter().max().unwrap() - all.iter().min().unwrap());
        }
        assert!(starts.len() > 10, "windows start all along the trajectory: {starts:?}");
        assert!(spread > 15, "without a window the views span the trajectory ({spread})");
        // A window of more frames than the scene has is the whole scene.
        let (views, _) = draw_views(
            4,
            &ViewPlan { window: Some(40), min_views: 3, max_views: 3, ..plan },
            &mut rng,
        );
        assert!(views.iter().all(|&v| v < 4) && views.len() == 4);
    }
}
