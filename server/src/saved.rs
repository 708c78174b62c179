//! A reconstruction folder written by `inssplat reconstruct`, read back: the Gaussians with
//! their instance ids (`scene.ply`), the predicted cameras at the photos' resolution
//! (`transforms.json`) and the instance table with semantic prototypes (`instances.json`).
//! `query` and `render` work from these files alone, without the network.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use inssplat_proto::dataset::TransformsJson;
use inssplat_proto::{Camera, GaussianScene, Intrinsics};
use inssplat_raster::label::InstancePrototype;

use crate::output::InstancesDoc;

/// The parts of a reconstruction folder.
pub struct Saved {
    pub dir: PathBuf,
    pub scene: GaussianScene,
    pub cameras: Vec<Camera>,
    pub doc: InstancesDoc,
}

impl Saved {
    /// Reads `dir`; errors name the file and what is wrong with it.
    pub fn load(dir: &Path) -> anyhow::Result<Self> {
        let ply = dir.join("scene.ply");
        let mut file = std::fs::File::open(&ply)
            .with_context(|| format!("{}: cannot open (is {} an `inssplat reconstruct` output?)", ply.display(), dir.display()))?;
        let scene = inssplat_proto::ply::read_ply(&mut std::io::BufReader::new(&mut file)).with_context(|| format!("{}", ply.display()))?;
        let json = dir.join("transforms.json");
        let text = std::fs::read_to_string(&json).with_context(|| format!("{}: cannot read", json.display()))?;
        let t: TransformsJson = serde_json::from_str(&text).with_context(|| format!("{}: not a transforms.json", json.display()))?;
        let cameras = t
            .frames
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let field = |v: Option<f64>, name: &str| v.with_context(|| format!("{}: frames[{i}].{name} is missing", json.display()));
                let (w, h) = (f.w.with_context(|| format!("{}: frames[{i}].w is missing", json.display()))?, f.h.with_context(|| format!("{}: frames[{i}].h is missing", json.display()))?);
                let k = Intrinsics {
                    fx: field(f.fl_x, "fl_x")? as f32,
                    fy: field(f.fl_y, "fl_y")? as f32,
                    cx: field(f.cx, "cx")? as f32,
                    cy: field(f.cy, "cy")? as f32,
                    width: w,
                    height: h,
                };
                Camera::from_nerfstudio(k, &f.transform_matrix).with_context(|| format!("{}: frames[{i}].transform_matrix", json.display()))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let path = dir.join("instances.json");
        let text = std::fs::read_to_string(&path).with_context(|| format!("{}: cannot read", path.display()))?;
        let doc: InstancesDoc = serde_json::from_str(&text).with_context(|| format!("{}: not an instances.json", path.display()))?;
        if cameras.is_empty() {
            bail!("{}: has no frames", json.display());
        }
        Ok(Self { dir: dir.to_path_buf(), scene, cameras, doc })
    }

    /// The semantic prototypes, as the label module takes them.
    pub fn prototypes(&self) -> Vec<InstancePrototype> {
        self.doc.prototypes.iter().map(|p| InstancePrototype { id: p.id, embedding: p.embedding.clone(), gaussians: p.gaussians }).collect()
    }

    /// Largest instance id.
    pub fn max_id(&self) -> usize {
        self.doc.instances.iter().map(|i| i.id as usize).max().unwrap_or(0)
    }
}
