//! inssplat-synth: procedural indoor scenes for training and evaluation, written in the
//! dataset format of docs/DATASET.md.
//! A seed fixes everything (ChaCha8 streams, no clocks, no hash-map order): the room and its
//! surface patterns, 1–3 lights, the furniture (Sweet Home 3D catalog meshes and furniture
//! built from primitives, with plausible groupings and several instances of a category), a
//! phone-like camera path, and the rendered RGB, depth and instance masks from a CPU ray
//! caster with Lambert shading, ambient light and hard shadows (the colour anti-aliased by
//! several rays a pixel if asked).
//!
//! The BVH is `obvhs`'s compressed-wide BVH: on an 80k-triangle mesh and 262k camera rays on
//! one core it traced 3.05 M rays/s against 1.04 M rays/s for the `bvh` crate (0.13,
//! `traverse_iterator`), with a similar build time (0.11 s vs 0.07 s); catalog models are
//! decimated to [`furniture::TRIANGLE_BUDGET`] triangles, so builds are milliseconds.
//!
//! Speed (release build, 128×128, 16 frames, catalog + primitives, PNGs written): about
//! 7 scenes/s on one core including the first load of every model (~80 ms each, cached per
//! process), 10 scenes/s primitives-only.
//!
//! Models in `eval-reserved-meshes.txt` never reach the train and val splits; the test split
//! includes them by default (that is what they are kept for: furniture never seen in
//! training), and `Reserved::Only` makes test scenes of unseen furniture alone.

pub mod camera_path;
pub mod catalog;
pub mod effects;
pub mod furniture;
pub mod layout;
pub mod mesh;
pub mod preview;
pub mod primitives;
pub mod raycast;
pub mod room;
pub mod split;
pub mod stats;
pub mod texture;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use inssplat_proto::camera::Intrinsics;
use inssplat_proto::dataset::{DEFAULT_DEPTH_UNIT_M, DatasetError, Frame, InstanceLabel, Scene};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

pub use catalog::{Catalog, Credit};

/// Every label a synthesized scene can carry: catalog furniture, primitive furniture and the
/// room shell.
pub fn all_labels() -> std::collections::BTreeSet<&'static str> {
    catalog::rule_labels()
        .chain(primitives::LABELS.iter().copied())
        .chain(stats::SHELL_LABELS)
        .collect()
}
pub use split::{Split, eval_split};
pub use stats::DatasetStats;

/// Where the furniture folder is looked for when `INSSPLAT_FURNITURE_DIR` is not set (the
/// Debian package `sweethome3d-furniture`).
pub const DEFAULT_FURNITURE_DIR: &str = "/usr/share/sweethome3d/furniture";

#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("furniture folder {}: {problem}", dir.display())]
    FurnitureDir { dir: PathBuf, problem: String },
    #[error("{}: {entry}: {problem}", archive.display())]
    Archive { archive: PathBuf, entry: String, problem: String },
    #[error("invalid configuration: {0}")]
    Config(String),
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
}

/// Whether walls, floor and ceiling are background (id 0) or instances of their own.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Structure {
    Background,
    Instances,
}

/// What to do with the furniture reserved for evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reserved {
    Exclude,
    Include,
    Only,
}

impl Reserved {
    /// Whether a model with the given reserved flag may be used.
    pub fn allows(self, reserved: bool) -> bool {
        match self {
            Reserved::Exclude => !reserved,
            Reserved::Include => true,
            // Primitives and unreserved catalog labels still fill gaps; catalog picks are
            // reserved models only.
            Reserved::Only => reserved,
        }
    }
}

/// Where furniture comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Furniture {
    /// Primitive furniture only; needs no files.
    Primitives,
    /// Sweet Home 3D catalog meshes from this folder, plus primitives.
    Catalog(PathBuf),
}

impl Furniture {
    /// The catalog at `INSSPLAT_FURNITURE_DIR`, or at [`DEFAULT_FURNITURE_DIR`].
    pub fn from_env() -> Furniture {
        Furniture::Catalog(
            std::env::var_os("INSSPLAT_FURNITURE_DIR")
                .map_or_else(|| DEFAULT_FURNITURE_DIR.into(), PathBuf::from),
        )
    }
}

/// The most rays per pixel side [`SynthConfig::antialias`] takes (64 rays a pixel).
pub const MAX_ANTIALIAS: u32 = 8;

/// Knobs of the synthesizer. Ranges are inclusive `(min, max)` drawn per scene; `noise`,
/// `blur` and `exposure` are per-frame maxima.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthConfig {
    pub split: Split,
    pub width: u32,
    pub height: u32,
    pub frames: (usize, usize),
    /// Objects per scene (including small things on tables).
    pub objects: (usize, usize),
    /// Probability, per extra object, of another instance of something already placed.
    pub repeat: f32,
    /// Multiplier of every procedural pattern's contrast (0 = flat colours).
    pub texture_contrast: f32,
    /// Sensor noise standard deviation, fraction of full scale.
    pub noise: f32,
    /// Gaussian blur sigma, pixels.
    pub blur: f32,
    /// Exposure jitter, stops (±).
    pub exposure: f32,
    /// View overlap along the path: 0 = the path spans the room, 1 = nearly still.
    pub overlap: (f32, f32),
    /// Vertical field of view, degrees.
    pub fov_y_deg: (f32, f32),
    pub structure: Structure,
    pub furniture: Furniture,
    pub reserved: Reserved,
    /// Probability of a catalog mesh where both a mesh and a primitive exist for a label.
    pub mesh_share: f32,
    /// Mark context/target views (`eval` in transforms.json) for `inssplat-eval score`: test
    /// always,
    /// val when asked (to choose between models on val scenes).
    pub eval_views: bool,
    /// Rays per pixel side for the colour (1: one ray through the pixel's centre, which
    /// aliases as no camera does; 2: the mean of 2×2). Depth and masks are the centre's.
    pub antialias: u32,
}

impl SynthConfig {
    /// Defaults for `split`: 128×128, 12–24 frames (24 for test, which also gets an
    /// evaluation split), reserved furniture excluded except in test.
    pub fn new(split: Split, furniture: Furniture) -> Self {
        SynthConfig {
            split,
            width: 128,
            height: 128,
            frames: if split == Split::Test { (24, 24) } else { (12, 24) },
            objects: (6, 14),
            repeat: 0.3,
            texture_contrast: 1.0,
            noise: 0.01,
            blur: 0.0,
            exposure: 0.3,
            overlap: (0.2, 0.8),
            fov_y_deg: (50.0, 80.0),
            structure: Structure::Background,
            furniture,
            reserved: if split == Split::Test { Reserved::Include } else { Reserved::Exclude },
            mesh_share: 0.6,
            eval_views: split == Split::Test,
            antialias: 1,
        }
    }

    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |m: String| Err(SynthError::Config(m));
        if self.split != Split::Test && self.reserved != Reserved::Exclude {
            return bad(format!(
                "reserved evaluation furniture cannot be used in the {} split",
                self.split
            ));
        }
        if self.width == 0 || self.height == 0 || self.width > 4096 || self.height > 4096 {
            return bad(format!("image size {}x{} is outside 1..=4096", self.width, self.height));
        }
        if self.frames.0 == 0 || self.frames.0 > self.frames.1 || self.frames.1 > 1000 {
            return bad(format!("frames {:?} must be 1 <= min <= max <= 1000", self.frames));
        }
        if self.objects.0 > self.objects.1 || self.objects.1 > 200 {
            return bad(format!("objects {:?} must be min <= max <= 200", self.objects));
        }
        if !(1.0..=170.0).contains(&self.fov_y_deg.0)
            || self.fov_y_deg.0 > self.fov_y_deg.1
            || self.fov_y_deg.1 > 170.0
        {
            return bad(format!(
                "field of view {:?} must be 1 <= min <= max <= 170 degrees",
                self.fov_y_deg
            ));
        }
        let unit = |name: &str, v: f32| {
            (0.0..=1.0).contains(&v).then_some(()).ok_or(format!("{name} {v} is outside 0..=1"))
        };
        unit("repeat", self.repeat)
            .and(unit("mesh share", self.mesh_share))
            .and(unit("overlap min", self.overlap.0))
            .and(unit("overlap max", self.overlap.1))
            .and(unit("noise", self.noise))
            .map_err(SynthError::Config)?;
        if self.overlap.0 > self.overlap.1
            || !(0.0..=20.0).contains(&self.blur)
            || !(0.0..=4.0).contains(&self.exposure)
        {
            return bad(
                "overlap min > max, blur outside 0..=20 px, or exposure outside 0..=4 stops".into(),
            );
        }
        if !(1..=MAX_ANTIALIAS).contains(&self.antialias) {
            return bad(format!(
                "anti-aliasing {} rays per pixel side is outside 1..={MAX_ANTIALIAS}",
                self.antialias
            ));
        }
        if !(0.0..=4.0).contains(&self.texture_contrast) {
            return bad(format!("texture contrast {} is outside 0..=4", self.texture_contrast));
        }
        Ok(())
    }
}

/// A synthesized scene and the credits of the catalog models visible in it.
#[derive(Debug, Clone, PartialEq)]
pub struct Synthesized {
    pub scene: Scene,
    pub credits: Vec<Credit>,
}

impl Synthesized {
    /// Writes the scene folder plus `credits.json` (model, creator, license per model used).
    pub fn write(&self, dir: &Path) -> Result<(), SynthError> {
        self.scene.write(dir)?;
        let path = dir.join("credits.json");
        let text = serde_json::to_string_pretty(&self.credits).expect("credits serialize");
        std::fs::write(&path, text).map_err(|source| SynthError::Io { path, source })
    }
}

/// The scene of `seed`.
pub fn generate(seed: u64, cfg: &SynthConfig) -> Result<Scene, SynthError> {
    generate_scene(seed, cfg).map(|s| s.scene)
}

/// Scene `index` of `cfg.split`.
pub fn generate_split(index: u64, cfg: &SynthConfig) -> Result<Synthesized, SynthError> {
    generate_scene(cfg.split.seed(index)?, cfg)
}

/// The random stream of `seed` after its room and furniture are drawn, with both.
fn furnished(
    seed: u64,
    cfg: &SynthConfig,
) -> Result<(ChaCha8Rng, room::Room, layout::Layout), SynthError> {
    cfg.validate()?;
    let catalog = match &cfg.furniture {
        Furniture::Primitives => None,
        Furniture::Catalog(dir) => Some(Catalog::open(dir)?),
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let room = room::Room::random(&mut rng, cfg.texture_contrast);
    let source = layout::Source {
        catalog: catalog.as_deref(),
        reserved: cfg.reserved,
        mesh_share: cfg.mesh_share,
        contrast: cfg.texture_contrast,
    };
    let furnished = layout::furnish(&room, &source, cfg, &mut rng);
    Ok((rng, room, furnished))
}

/// The scene of `seed`, with credits.
pub fn generate_scene(seed: u64, cfg: &SynthConfig) -> Result<Synthesized, SynthError> {
    let (mut rng, room, furnished) = furnished(seed, cfg)?;
    let n = furnished.objects.len();
    let ids: Vec<u16> = (1..=n as u16).collect();
    let shell_ids: raycast::ShellIds = match cfg.structure {
        Structure::Background => [0; 6],
        Structure::Instances => std::array::from_fn(|i| (n + 1 + i) as u16),
    };
    let world = raycast::World::new(&room, &furnished.objects, &ids, shell_ids);

    let n_frames = rng.random_range(cfg.frames.0..=cfg.frames.1);
    let fov = rng.random_range(cfg.fov_y_deg.0..=cfg.fov_y_deg.1).to_radians();
    let k = Intrinsics::from_fov_y(cfg.width, cfg.height, fov);
    let overlap = rng.random_range(cfg.overlap.0..=cfg.overlap.1);
    let cameras = camera_path::cameras(&world, n_frames, overlap, k, &mut rng);
    let buffers: Vec<raycast::FrameBuffers> =
        cameras.par_iter().map(|c| world.render(c, cfg.antialias)).collect();

    let radiance: Vec<&[glam::Vec3]> = buffers.iter().map(|b| b.radiance.as_slice()).collect();
    let base = effects::auto_exposure(&radiance);
    let (w, h) = (cfg.width as usize, cfg.height as usize);
    let frames: Vec<Frame> = buffers
        .into_iter()
        .zip(&cameras)
        .map(|(b, cam)| {
            let shot = effects::Shot::random(&mut rng, base, cfg.exposure, cfg.blur, cfg.noise);
            Frame {
                camera: *cam,
                rgb: shot.develop(&b.radiance, w, h),
                depth: Some(b.depth),
                instances: Some(b.ids),
            }
        })
        .collect();

    // List only what some frame shows.
    let visible: BTreeSet<u16> =
        frames.iter().flat_map(|f| f.instances.iter().flatten().copied()).collect();
    let mut instances = Vec::new();
    let mut credits = BTreeSet::new();
    for (o, &id) in furnished.objects.iter().zip(&ids) {
        if visible.contains(&id) {
            instances.push(InstanceLabel { id: u32::from(id), label: o.model.label.to_string() });
            credits.extend(o.model.credit.clone());
        }
    }
    for (surface, &id) in room::Surface::ALL.iter().zip(&shell_ids) {
        if id != 0 && visible.contains(&id) {
            instances.push(InstanceLabel { id: u32::from(id), label: surface.label().to_string() });
        }
    }
    let eval = if cfg.eval_views { eval_split(frames.len()) } else { None };
    let scene =
        Scene { dir: PathBuf::new(), instances, frames, eval, depth_unit_m: DEFAULT_DEPTH_UNIT_M };
    Ok(Synthesized { scene, credits: credits.into_iter().collect() })
}
