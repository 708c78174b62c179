//! A reconstruction folder written by `inssplat reconstruct`, read back: the Gaussians with
//! their instance ids (`scene.ply`), the predicted cameras at the photos' resolution
//! (`transforms.json`) and the instance table with semantic prototypes (`instances.json`).
//! `query` and `render` work from these files alone, without the network.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use inssplat_proto::dataset::TransformsJson;
use inssplat_proto::{Camera, GaussianScene};
use inssplat_understand::label::InstancePrototype;

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
        let mut file = std::fs::File::open(&ply).with_context(|| {
            format!(
                "{}: cannot open (is {} an `inssplat reconstruct` output?)",
                ply.display(),
                dir.display()
            )
        })?;
        let scene = inssplat_proto::ply::read_ply(&mut std::io::BufReader::new(&mut file))
            .with_context(|| format!("{}", ply.display()))?;
        let json = dir.join("transforms.json");
        let t = TransformsJson::read(&json)?;
        let cameras = t.cameras(&json)?;
        let path = dir.join("instances.json");
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        let doc: InstancesDoc = serde_json::from_str(&text)
            .with_context(|| format!("{}: not an instances.json", path.display()))?;
        if cameras.is_empty() {
            bail!("{}: has no frames", json.display());
        }
        Ok(Self { dir: dir.to_path_buf(), scene, cameras, doc })
    }

    /// The semantic prototypes, as the label module takes them.
    pub fn prototypes(&self) -> Vec<InstancePrototype> {
        self.doc
            .prototypes
            .iter()
            .map(|p| InstancePrototype {
                id: p.id,
                embedding: p.embedding.clone(),
                gaussians: p.gaussians,
            })
            .collect()
    }
}
