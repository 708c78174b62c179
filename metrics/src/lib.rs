//! inssplat-metrics: the numbers of the evaluation protocol (docs/EVALUATION.md), each a pure
//! function of predicted and ground-truth arrays: semantic mIoU/mAcc, instance mIoU and
//! Acc@0.25, cross-view consistency T-mIoU and T-SR@0.5, text-query IoU
//! ([`segmentation`]); PSNR, SSIM and depth AbsRel ([`image`]); camera errors after a similarity
//! alignment ([`pose`]). A metric that the inputs cannot give (no ground-truth
//! instance, no valid depth) is `None`, never zero.

pub mod image;
pub mod pose;
pub mod segmentation;

pub use image::{
    DepthScores, SSIM_SIGMA, SSIM_WINDOW, depth_abs_rel, depth_abs_rel_where, psnr, ssim,
};
pub use pose::{AlignScale, PoseScores, Similarity, camera_errors, pose_alignment};
pub use segmentation::{
    ConsistencyScores, InstanceMatch, InstancePool, InstanceScores, PanopticCounts, SemanticScores,
    consistency_scores, instance_scores, mask_iou, semantic_scores,
};

/// Why a metric cannot be computed from its inputs.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricError {
    #[error("{what}: prediction has {pred} values, ground truth {gt}")]
    Length { what: &'static str, pred: usize, gt: usize },
    #[error("{what}: {width}×{height}×{channels} needs {expected} values, got {actual}")]
    Shape {
        what: &'static str,
        width: usize,
        height: usize,
        channels: usize,
        expected: usize,
        actual: usize,
    },
    #[error("SSIM needs images of at least {SSIM_WINDOW}×{SSIM_WINDOW}, got {width}×{height}")]
    TooSmall { width: usize, height: usize },
}

fn same_len(what: &'static str, pred: usize, gt: usize) -> Result<(), MetricError> {
    if pred == gt { Ok(()) } else { Err(MetricError::Length { what, pred, gt }) }
}
