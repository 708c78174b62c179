//! HTTP request and response bodies (serde), shared by the server, its tests and any Rust
//! client. Also the shape of the CLI's `--json` output and `instances.json`, so a scene
//! reads the same whichever way it was made. With the `openapi` feature every type also
//! describes itself as an OpenAPI schema (the server's `/openapi.json`).

use serde::{Deserialize, Serialize};

/// The one error shape of every non-2xx response.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ErrorBody {
    pub error: String,
    /// snake_case kind: `validation`, `payload_too_large`, `overloaded`, ...
    pub error_type: String,
}

/// A predicted camera, nerfstudio convention (OpenGL camera-to-world, row-major).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct CameraOut {
    pub view: usize,
    pub transform_matrix: [[f64; 4]; 4],
    pub fl_x: f32,
    pub fl_y: f32,
    pub cx: f32,
    pub cy: f32,
    pub w: u32,
    pub h: u32,
    /// How the pose was found (absent in scenes saved before it was reported).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub placement: Option<Placement>,
    /// Where the focal length came from, the same for every camera of a scene (absent in
    /// scenes saved before it was reported).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focal: Option<FocalSource>,
    /// How well registration fit this photo (absent where it did not run): a photo with few
    /// matches or a large error is the one to retake.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit: Option<CameraFit>,
}

/// The keypoint evidence behind one registered camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct CameraFit {
    /// Keypoints found in the photo.
    pub keypoints: usize,
    /// Matches to the other photos that agree with the registered poses.
    pub matches: usize,
    /// Median reprojection error of those matches (the other photos' keypoints, lifted by
    /// their depth), in this photo's pixels; absent without matches.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reprojection_px: Option<f32>,
}

/// Where a scene's focal length (its field of view) came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub enum FocalSource {
    /// Measured from the keypoint matches between the photos.
    Measured,
    /// The camera head's guess: registration off, or the matched photos do not pin the focal
    /// length down (few pairs, or photos that barely turn).
    CameraHead,
    /// Given by the caller with the poses.
    Given,
    /// From the photo's EXIF: its 35 mm-equivalent focal length, or its focal length and the
    /// sensor's resolution.
    Exif,
}

/// How a camera's pose was found: how far to trust it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub enum Placement {
    /// The first photo: its camera is the scene's frame.
    Reference,
    /// Linked to the first photo through keypoint matches.
    Registered,
    /// Linked to the first photo by no match (too little overlap): placed by continuing the
    /// camera's motion over the photos before it, or chained to a photo so placed, then
    /// turned to the heading at which the photos placed before it match it best, where one
    /// matches clearly better (the stage "heading").
    Continued,
    /// The camera head's pose as the network predicted it (registration off, or the second
    /// photo when no match links it, and the photos chained to it).
    CameraHead,
    /// Given by the caller (known poses).
    Given,
}

/// An instance of the reconstructed scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct InstanceOut {
    pub id: u32,
    pub label: String,
    /// Cosine similarity of the instance's semantic prototype to the label's text embedding.
    pub score: f32,
    pub gaussians: usize,
    /// Axis-aligned bounding box in the scene frame: min xyz, max xyz.
    pub bbox: [[f32; 3]; 2],
    /// Which evidence gave the label (absent in outputs written before 0.15: `features`).
    #[serde(default)]
    pub named_by: NamedBy,
    /// The object detector's strongest class for this instance, where it found any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector: Option<DetectorVote>,
}

/// The evidence that named an instance: each kind moves its semantic prototype in the text
/// space, and the label is the one the last kind that changed the nearest word chose.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum NamedBy {
    /// The network's semantic features alone.
    #[default]
    Features,
    /// The shape classifier (size, height above the floor, colour) moved it to this label.
    Shape,
    /// The object detector's boxes in the photos moved it to this label.
    Detector,
}

/// What the object detector said of an instance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct DetectorVote {
    /// The detector's class (COCO's name, e.g. `couch`).
    pub class: String,
    /// Its vote in [0, 1]: the box score × the box's IoU with the instance's pixels, averaged
    /// over the views weighted by how much of the instance each sees.
    pub vote: f32,
    /// Views that see the instance.
    pub views: usize,
}

/// Wall time of one pipeline stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StageTiming {
    pub stage: String,
    pub ms: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ReconstructResponse {
    pub scene_id: String,
    pub cameras: Vec<CameraOut>,
    pub instances: Vec<InstanceOut>,
    pub timings: Vec<StageTiming>,
    /// Per-pixel Gaussians in, Gaussians kept after voxelization.
    pub gaussians_in: usize,
    pub gaussians_kept: usize,
    /// What the test-time refinement against the photos did (absent when it did not run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refinement: Option<RefinementOut>,
    /// What the user should know about the photos, one sentence each, naming the view: a
    /// photo sent twice, one no match links (its pose is a guess), one barely linked, one with
    /// too little texture.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// The test-time refinement of a reconstruction against its own photos: its Adam steps, the
/// input views' PSNR (dB, inside the photos, averaged over views; the Gaussians as they
/// render) before and after, and each photo's brightness gain that the fit found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct RefinementOut {
    pub steps: usize,
    pub input_psnr_before: f64,
    pub input_psnr_after: f64,
    /// One per input photo, in their order: how much brighter than the Gaussians' colours the
    /// photo came out (its camera's auto exposure); their logs average zero.
    pub photo_gains: Vec<f32>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct QueryRequest {
    pub text: String,
}

/// A binary mask, run-length encoded in row-major order starting with a run of zeros
/// (COCO-style counts, but row-major).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct RleMask {
    pub width: u32,
    pub height: u32,
    pub counts: Vec<u32>,
}

impl RleMask {
    pub fn encode(width: u32, height: u32, mask: &[bool]) -> Self {
        let mut counts = Vec::new();
        let mut current = false;
        let mut run = 0u32;
        for &m in mask {
            if m != current {
                counts.push(run);
                run = 0;
                current = m;
            }
            run += 1;
        }
        counts.push(run);
        Self { width, height, counts }
    }

    pub fn decode(&self) -> Vec<bool> {
        let mut out = Vec::with_capacity((self.width * self.height) as usize);
        for (i, &c) in self.counts.iter().enumerate() {
            out.extend(std::iter::repeat_n(i % 2 == 1, c as usize));
        }
        out
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ViewMask {
    pub view: usize,
    pub png_url: String,
    pub rle: RleMask,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct QueryMatch {
    pub instance_id: u32,
    pub label: String,
    pub score: f32,
    pub masks: Vec<ViewMask>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct QueryResponse {
    pub text: String,
    /// Empty when nothing in the scene matches; `message` then says so.
    pub matches: Vec<QueryMatch>,
    pub message: Option<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    Queued,
    Running,
    Done,
    Failed,
    Cancelled,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct JobSceneStatus {
    pub index: usize,
    pub name: String,
    pub state: JobState,
    pub scene_id: Option<String>,
    pub error: Option<String>,
    /// Evaluation metrics when the scene carried ground truth (the `inssplat-eval score` scene
    /// record: semantic/instance mIoU, query IoU, T-mIoU, PSNR, SSIM, depth, cameras, time).
    #[cfg_attr(feature = "openapi", schema(value_type = Option<Object>))]
    pub metrics: Option<serde_json::Value>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct JobStatus {
    pub job_id: String,
    pub state: JobState,
    pub done: usize,
    pub total: usize,
    pub scenes: Vec<JobSceneStatus>,
}

/// The answer to a job submission.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct JobAccepted {
    pub job_id: String,
    /// Scenes in the job, each a named set of photos or a dataset scene folder.
    pub scenes: Vec<String>,
}

/// `/health` and `/ready`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ServiceStatus {
    /// `ok`, `ready` or `warming_up`.
    pub status: String,
    /// The loaded network's version, once it is loaded.
    pub model_version: Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rle_round_trips_and_starts_with_zeros() {
        let mask = [true, true, false, false, false, true, false];
        let rle = RleMask::encode(7, 1, &mask);
        assert_eq!(rle.counts, [0, 2, 3, 1, 1]);
        assert_eq!(rle.decode(), mask);
        assert_eq!(RleMask::encode(2, 1, &[false, false]).counts, [2]);
    }

    #[test]
    fn enums_serialize_snake_case() {
        assert_eq!(serde_json::to_string(&JobState::Cancelled).unwrap(), "\"cancelled\"");
    }
}
