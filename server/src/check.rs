//! `inssplat check`: validates dataset scene folders with the `proto` reader and summarizes
//! them, so a user learns what is wrong with a scene before anything runs on it.

use std::path::Path;

use anyhow::Context;
use inssplat_proto::dataset::Scene;
use serde::Serialize;

/// What a valid scene holds.
#[derive(Debug, Serialize)]
pub struct SceneSummary {
    pub path: String,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub with_depth: usize,
    pub with_instances: usize,
    pub instances: usize,
    pub labels: Vec<String>,
    pub has_eval_split: bool,
}

/// Loads and validates the scene in `dir`.
pub fn check_scene(dir: &Path) -> anyhow::Result<SceneSummary> {
    let scene =
        Scene::load(dir).with_context(|| format!("scene {} is not valid", dir.display()))?;
    let first = &scene.frames[0];
    Ok(SceneSummary {
        path: dir.display().to_string(),
        frames: scene.frames.len(),
        width: first.width(),
        height: first.height(),
        with_depth: scene.frames.iter().filter(|f| f.depth.is_some()).count(),
        with_instances: scene.frames.iter().filter(|f| f.instances.is_some()).count(),
        instances: scene.instances.len(),
        labels: scene.label_vocabulary(),
        has_eval_split: scene.eval.is_some(),
    })
}

impl SceneSummary {
    /// One line for people.
    pub fn describe(&self) -> String {
        format!(
            "{}: ok, {} frames {}×{}, depth in {}, instance masks in {}, {} instances ({}){}",
            self.path,
            self.frames,
            self.width,
            self.height,
            self.with_depth,
            self.with_instances,
            self.instances,
            self.labels.join(", "),
            if self.has_eval_split { ", eval split" } else { "" }
        )
    }
}
