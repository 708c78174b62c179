//! The scene dataset format (docs/DATASET.md): one folder per scene, nerfstudio `transforms.json`
//! extended with 16-bit depth, 16-bit instance masks, instance labels and an optional
//! context/target split for evaluation. [`Scene::load`] reads and validates a folder,
//! [`Scene::write`] writes one; every rejection names the file and the field.

mod error;
mod read;
mod transforms;
mod write;

pub use error::{DatasetError, Problem};
pub use transforms::{EvalSplit, FrameJson, InstanceLabel, TransformsJson};

use std::path::PathBuf;

use crate::camera::Camera;

/// Default depth quantum: millimetres.
pub const DEFAULT_DEPTH_UNIT_M: f64 = 0.001;

/// A loaded, validated scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Folder the scene was read from (empty for scenes built in memory).
    pub dir: PathBuf,
    pub instances: Vec<InstanceLabel>,
    pub frames: Vec<Frame>,
    pub eval: Option<EvalSplit>,
    /// Depth quantum in metres used when the scene is written.
    pub depth_unit_m: f64,
}

/// One view: camera, image and the optional ground truth that comes with it.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub camera: Camera,
    /// 8-bit RGB, row-major, `width · height · 3`.
    pub rgb: Vec<u8>,
    /// Depth along the camera z axis in metres, 0 = no hit, `width · height`.
    pub depth: Option<Vec<f32>>,
    /// Instance id per pixel, 0 = no instance, `width · height`.
    pub instances: Option<Vec<u16>>,
}

impl Frame {
    pub fn width(&self) -> u32 {
        self.camera.intrinsics.width
    }

    pub fn height(&self) -> u32 {
        self.camera.intrinsics.height
    }

    /// The image as planar `[3][H][W]` values in [0, 1] (the network's and the renderer's
    /// layout).
    pub fn planar_rgb(&self) -> Vec<f32> {
        (0..3)
            .flat_map(|c| self.rgb.chunks_exact(3).map(move |px| f32::from(px[c]) / 255.0))
            .collect()
    }
}

impl Scene {
    /// The scene's folder name (the whole path if it has none), for messages and reports.
    pub fn name(&self) -> String {
        self.dir
            .file_name()
            .map_or_else(|| self.dir.display().to_string(), |n| n.to_string_lossy().into_owned())
    }

    /// Label of instance `id`, if listed.
    pub fn label_of(&self, id: u16) -> Option<&str> {
        self.instances.iter().find(|i| i.id == u32::from(id)).map(|i| i.label.as_str())
    }

    /// Sorted, de-duplicated instance labels.
    pub fn label_vocabulary(&self) -> Vec<String> {
        let mut v: Vec<String> = self.instances.iter().map(|i| i.label.clone()).collect();
        v.sort();
        v.dedup();
        v
    }
}

#[cfg(test)]
mod tests;
