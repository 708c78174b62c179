//! NanoDet's outputs to boxes: per level (stride 8, 16, 32) a row-major grid of anchor points
//! at the cells' centres, each with 80 class scores and, for each side (left, top, right,
//! bottom), a distribution over [`BINS`] distances in strides whose expectation is the side's
//! distance from the point (Generalized Focal Loss); then per-class non-maximum suppression.

use inssplat_understand::label::detections::box_iou;

/// Classes the detector scores (COCO's).
pub const CLASSES: usize = 80;
/// Distance bins per box side.
pub const BINS: usize = 11;
/// Strides of the output levels, finest first.
pub const STRIDES: [usize; 3] = [8, 16, 32];
const SIDE: usize = super::SIDE;

/// One output level: `scores` `[points][CLASSES]` (after the sigmoid), `distances`
/// `[points][4][BINS]` (logits), points row-major over the `SIDE / stride` grid.
#[derive(Debug, Clone)]
pub struct Level {
    pub stride: usize,
    pub scores: Vec<f32>,
    pub distances: Vec<f32>,
}

/// One detected object.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// Index into the detector's class list.
    pub class: usize,
    pub score: f32,
    /// `[x0, y0, x1, y1]` in pixels (of the detector's input until scaled to the photo).
    pub bbox: [f32; 4],
}

/// Every (point, class) whose score reaches `min_score`, as a box in input pixels clipped to
/// the input.
pub fn decode(levels: &[Level], min_score: f32) -> Vec<Detection> {
    let mut found = Vec::new();
    for level in levels {
        let cols = SIDE / level.stride;
        let points = level.scores.len() / CLASSES;
        for p in 0..points {
            let scores = &level.scores[p * CLASSES..(p + 1) * CLASSES];
            if !scores.iter().any(|&s| s >= min_score) {
                continue;
            }
            let centre =
                [(p % cols) as f32, (p / cols) as f32].map(|c| (c + 0.5) * level.stride as f32);
            let bins = &level.distances[p * 4 * BINS..(p + 1) * 4 * BINS];
            let d: Vec<f32> =
                bins.chunks_exact(BINS).map(|b| expectation(b) * level.stride as f32).collect();
            let clip = |v: f32| v.clamp(0.0, SIDE as f32);
            let bbox = [
                clip(centre[0] - d[0]),
                clip(centre[1] - d[1]),
                clip(centre[0] + d[2]),
                clip(centre[1] + d[3]),
            ];
            for (class, &score) in scores.iter().enumerate().filter(|(_, s)| **s >= min_score) {
                found.push(Detection { class, score, bbox });
            }
        }
    }
    found
}

/// The expected bin index under the softmax of `logits`.
fn expectation(logits: &[f32]) -> f32 {
    let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let e: Vec<f32> = logits.iter().map(|l| (l - max).exp()).collect();
    let sum: f32 = e.iter().sum();
    e.iter().enumerate().map(|(i, v)| i as f32 * v).sum::<f32>() / sum
}

/// Greedy per-class non-maximum suppression: strongest first, a box dropped when it overlaps a
/// kept box of its class by more than `iou`. The kept ones, strongest first.
pub fn non_maximum_suppression(mut found: Vec<Detection>, iou: f32) -> Vec<Detection> {
    found.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept: Vec<Detection> = Vec::new();
    for d in found {
        if !kept.iter().any(|k| k.class == d.class && box_iou(&k.bbox, &d.bbox) > iou) {
            kept.push(d);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level(stride: usize, point: usize, class: usize, score: f32, bins: [usize; 4]) -> Level {
        let points = (SIDE / stride).pow(2);
        let mut scores = vec![0.0; points * CLASSES];
        scores[point * CLASSES + class] = score;
        let mut distances = vec![-50.0; points * 4 * BINS];
        for (side, bin) in bins.iter().enumerate() {
            distances[point * 4 * BINS + side * BINS + bin] = 50.0;
        }
        Level { stride, scores, distances }
    }

    #[test]
    fn a_point_decodes_to_its_distances_in_strides_around_it() {
        // Point (3, 2) of the stride-16 grid (26 columns): centre (56, 40).
        let l = level(16, 2 * 26 + 3, 56, 0.8, [1, 2, 3, 4]);
        let found = decode(&[l], 0.3);
        assert_eq!(found.len(), 1);
        let d = found[0];
        assert_eq!((d.class, d.score), (56, 0.8));
        let want = [56.0 - 16.0, 40.0 - 32.0, 56.0 + 48.0, 40.0 + 64.0];
        for (a, b) in d.bbox.iter().zip(want) {
            assert!((a - b).abs() < 1e-3, "{:?} against {want:?}", d.bbox);
        }
    }

    #[test]
    fn boxes_are_clipped_to_the_input_and_weak_scores_dropped() {
        let l = level(32, 0, 0, 0.5, [10, 10, 1, 1]);
        let d = decode(std::slice::from_ref(&l), 0.3)[0];
        assert_eq!(d.bbox[..2], [0.0, 0.0]);
        assert!(decode(&[l], 0.6).is_empty());
    }

    #[test]
    fn suppression_keeps_the_strongest_of_a_class_and_other_classes_beside_it() {
        let d = |class, score, x0| Detection { class, score, bbox: [x0, 0.0, x0 + 10.0, 10.0] };
        let kept = non_maximum_suppression(
            vec![d(1, 0.5, 1.0), d(1, 0.9, 0.0), d(2, 0.4, 0.0), d(1, 0.6, 50.0)],
            0.5,
        );
        assert_eq!(kept, vec![d(1, 0.9, 0.0), d(1, 0.6, 50.0), d(2, 0.4, 0.0)]);
    }
}
