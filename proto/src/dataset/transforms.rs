//! The JSON shape of `transforms.json`, as serde types. Unknown fields are kept out of the
//! way (nerfstudio files carry many); validation happens in `read`.
//!
//! The intrinsics (`fl_x` … `h`) are spelled out in both [`TransformsJson`] and [`FrameJson`]
//! rather than shared through a `#[serde(flatten)]` struct: flatten buffers the fields and
//! loses their path, so a bad `frames[1].fl_y` would be reported as `frames[1]` alone
//! (dtolnay/path-to-error#9; the test `rejects_wrong_types` holds the field names).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransformsJson {
    #[serde(default = "opencv")]
    pub camera_model: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fl_x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fl_y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub w: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub h: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_unit_m: Option<f64>,
    #[serde(default)]
    pub instances: Vec<InstanceLabel>,
    pub frames: Vec<FrameJson>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub eval: Option<EvalSplit>,
}

fn opencv() -> String {
    "OPENCV".to_string()
}

#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InstanceLabel {
    pub id: u32,
    pub label: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameJson {
    pub file_path: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_file_path: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instance_file_path: Option<String>,
    /// Camera-to-world, OpenGL axes, row-major.
    pub transform_matrix: [[f64; 4]; 4],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fl_x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fl_y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub w: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub h: Option<u32>,
}

/// Frame indices for evaluation: context (input) sets per view count, and target views that
/// are never input.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct EvalSplit {
    /// View count ("2", "4", ...) → frame indices.
    pub context: BTreeMap<String, Vec<usize>>,
    pub target: Vec<usize>,
}

impl EvalSplit {
    /// Context frames for `views` input views, if the split defines them.
    pub fn context_for(&self, views: usize) -> Option<&[usize]> {
        self.context.get(&views.to_string()).map(Vec::as_slice)
    }
}
