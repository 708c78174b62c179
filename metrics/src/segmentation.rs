//! Segmentation metrics on id and label maps (row-major pixels; several views are passed
//! concatenated unless a function takes views separately).
//! - Semantic mIoU / mAcc: over the classes present in the ground truth; pixels whose ground
//!   truth is [`NO_LABEL`] are ignored; mAcc is the mean per-class recall.
//! - Instance mIoU / Acc@0.25 (OpenGaussian/LERF protocol): for each ground-truth instance
//!   (id ≠ 0) the best IoU over predicted ids ≠ 0; Acc@0.25 = share with IoU > 0.25.
//! - Instance PQ (panoptic quality, class-agnostic): a prediction and a ground-truth instance
//!   match when their IoU exceeds ½, which makes every match unique; PQ = Σ IoU over matches /
//!   (matches + ½ unmatched predictions + ½ unmatched instances). Unlike instance mIoU it
//!   charges an object split into pieces, and a prediction with no object.
//! - T-mIoU / T-SR@0.5 (IGGT): each ground-truth instance gets ONE predicted id for all views,
//!   the one with the largest total overlap; T-mIoU = mean over instances of the mean IoU of
//!   that id over the views where the instance is visible; T-SR@0.5 = share of instances with
//!   IoU ≥ 0.5 in every such view.
//! - Text-query IoU: IoU of two boolean masks.

use std::collections::{BTreeMap, HashMap};

use inssplat_raster::masks::NO_LABEL;

use super::{MetricError, same_len};

#[derive(Debug, Clone, PartialEq)]
pub struct SemanticScores {
    pub miou: f64,
    pub macc: f64,
    /// Classes present in the ground truth.
    pub classes: usize,
}

/// Semantic mIoU and mAcc; `None` when the ground truth has no labelled pixel.
pub fn semantic_scores(pred: &[u32], gt: &[u32]) -> Result<Option<SemanticScores>, MetricError> {
    same_len("semantic label maps", pred.len(), gt.len())?;
    // Per ground-truth class: (intersection, gt count); predicted counts over non-ignored pixels.
    // Ordered, so the classes' sum is the same float in every run.
    let mut per_class: BTreeMap<u32, (u64, u64)> = BTreeMap::new();
    let mut predicted: HashMap<u32, u64> = HashMap::new();
    for (&p, &g) in pred.iter().zip(gt) {
        if g == NO_LABEL {
            continue;
        }
        let e = per_class.entry(g).or_default();
        e.1 += 1;
        if p == g {
            e.0 += 1;
        }
        *predicted.entry(p).or_default() += 1;
    }
    if per_class.is_empty() {
        return Ok(None);
    }
    let (mut iou, mut acc) = (0.0, 0.0);
    for (c, &(inter, g)) in &per_class {
        let p = predicted.get(c).copied().unwrap_or(0);
        iou += inter as f64 / (g + p - inter) as f64;
        acc += inter as f64 / g as f64;
    }
    let n = per_class.len() as f64;
    Ok(Some(SemanticScores { miou: iou / n, macc: acc / n, classes: per_class.len() }))
}

/// Pixel counts of one pair of id maps: intersections of (pred, gt) with both ≠ 0, and the
/// size of every id on each side.
#[derive(Default)]
struct Overlap {
    inter: HashMap<(u32, u32), u64>,
    pred: HashMap<u32, u64>,
    gt: HashMap<u32, u64>,
}

impl Overlap {
    fn new(pred: &[u32], gt: &[u32]) -> Self {
        let mut o = Self::default();
        for (&p, &g) in pred.iter().zip(gt) {
            if p != 0 {
                *o.pred.entry(p).or_default() += 1;
            }
            if g != 0 {
                *o.gt.entry(g).or_default() += 1;
            }
            if p != 0 && g != 0 {
                *o.inter.entry((p, g)).or_default() += 1;
            }
        }
        o
    }

    fn iou(&self, p: u32, g: u32) -> f64 {
        let i = self.inter.get(&(p, g)).copied().unwrap_or(0);
        let u = self.pred.get(&p).copied().unwrap_or(0) + self.gt.get(&g).copied().unwrap_or(0) - i;
        if u == 0 { 0.0 } else { i as f64 / u as f64 }
    }
}

/// A ground-truth instance and its best predicted match (`pred` 0 when nothing overlaps).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstanceMatch {
    pub gt: u32,
    pub pred: u32,
    pub iou: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct InstanceScores {
    pub miou: f64,
    /// Share of ground-truth instances with IoU > 0.25.
    pub acc_25: f64,
    /// Per ground-truth instance, in id order.
    pub matches: Vec<InstanceMatch>,
    pub panoptic: PanopticCounts,
}

/// What panoptic quality is computed from; counts of several views add up before [`Self::pq`]
/// (COCO's PQ pools its images the same way). An unmatched prediction lying mostly on
/// unlabelled pixels (ground truth 0) is no false positive, as in COCO.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PanopticCounts {
    /// Sum of the IoUs of the matched pairs.
    pub matched_iou: f64,
    pub true_positives: usize,
    pub false_positives: usize,
    pub false_negatives: usize,
}

impl PanopticCounts {
    pub fn add(&mut self, other: &Self) {
        self.matched_iou += other.matched_iou;
        self.true_positives += other.true_positives;
        self.false_positives += other.false_positives;
        self.false_negatives += other.false_negatives;
    }

    /// PQ in [0, 1]; `None` when neither side has a segment.
    pub fn pq(&self) -> Option<f64> {
        let denominator =
            self.true_positives as f64 + 0.5 * (self.false_positives + self.false_negatives) as f64;
        (denominator > 0.0).then(|| self.matched_iou / denominator)
    }
}

/// Instance mIoU and Acc@0.25; `None` when the ground truth has no instance.
pub fn instance_scores(pred: &[u32], gt: &[u32]) -> Result<Option<InstanceScores>, MetricError> {
    same_len("instance id maps", pred.len(), gt.len())?;
    let o = Overlap::new(pred, gt);
    let mut gts: Vec<u32> = o.gt.keys().copied().collect();
    if gts.is_empty() {
        return Ok(None);
    }
    gts.sort_unstable();
    let matches: Vec<InstanceMatch> = gts
        .iter()
        .map(|&g| {
            let mut best = InstanceMatch { gt: g, pred: 0, iou: 0.0 };
            for &(p, g2) in o.inter.keys() {
                let iou = o.iou(p, g);
                if g2 == g && (iou > best.iou || (iou == best.iou && p < best.pred)) {
                    best = InstanceMatch { gt: g, pred: p, iou };
                }
            }
            best
        })
        .collect();
    let n = matches.len() as f64;
    Ok(Some(InstanceScores {
        miou: matches.iter().map(|m| m.iou).sum::<f64>() / n,
        acc_25: matches.iter().filter(|m| m.iou > 0.25).count() as f64 / n,
        panoptic: panoptic_counts(&o, &matches),
        matches,
    }))
}

/// Instance scores of several views pooled: mIoU and Acc@0.25 over every view's true
/// instances, PQ over the views' summed counts. `inssplat-eval score` and `fit-scene` both pool
/// their target views with it, so that they score alike.
#[derive(Debug, Clone, Default)]
pub struct InstancePool {
    ious: Vec<f64>,
    panoptic: PanopticCounts,
}

impl InstancePool {
    pub fn add(&mut self, scores: &InstanceScores) {
        self.ious.extend(scores.matches.iter().map(|m| m.iou));
        self.panoptic.add(&scores.panoptic);
    }

    /// `None` (as for the two below) when no view had a true instance.
    pub fn miou(&self) -> Option<f64> {
        (!self.ious.is_empty()).then(|| self.ious.iter().sum::<f64>() / self.ious.len() as f64)
    }

    pub fn acc_25(&self) -> Option<f64> {
        (!self.ious.is_empty()).then(|| {
            self.ious.iter().filter(|&&x| x > 0.25).count() as f64 / self.ious.len() as f64
        })
    }

    pub fn pq(&self) -> Option<f64> {
        self.panoptic.pq()
    }
}

/// Above IoU ½ a ground-truth instance's best prediction is its only possible match and
/// that prediction's only one, so the best matches are the panoptic matches.
fn panoptic_counts(o: &Overlap, best: &[InstanceMatch]) -> PanopticCounts {
    let matched: Vec<&InstanceMatch> = best.iter().filter(|m| m.iou > 0.5).collect();
    let mut labelled: HashMap<u32, u64> = HashMap::new();
    for (&(p, _), &n) in &o.inter {
        *labelled.entry(p).or_default() += n;
    }
    let false_positives = o
        .pred
        .iter()
        .filter(|&(p, &size)| {
            !matched.iter().any(|m| m.pred == *p)
                && 2 * labelled.get(p).copied().unwrap_or(0) >= size
        })
        .count();
    PanopticCounts {
        matched_iou: matched.iter().map(|m| m.iou).sum(),
        true_positives: matched.len(),
        false_positives,
        false_negatives: best.len() - matched.len(),
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct ConsistencyScores {
    pub t_miou: f64,
    /// Share of instances with IoU ≥ 0.5 in every view where they are visible.
    pub t_sr: f64,
    pub instances: usize,
}

/// T-mIoU and T-SR@0.5 over views given as (predicted ids, ground-truth ids) pairs; `None`
/// when no view shows a ground-truth instance.
pub fn consistency_scores(
    views: &[(&[u32], &[u32])],
) -> Result<Option<ConsistencyScores>, MetricError> {
    let mut overlaps = Vec::with_capacity(views.len());
    for (pred, gt) in views {
        same_len("instance id maps of a view", pred.len(), gt.len())?;
        overlaps.push(Overlap::new(pred, gt));
    }
    // Total overlap of every (pred, gt) pair over all views.
    let mut total: HashMap<(u32, u32), u64> = HashMap::new();
    let mut gts: Vec<u32> = Vec::new();
    for o in &overlaps {
        for (&k, &n) in &o.inter {
            *total.entry(k).or_default() += n;
        }
        gts.extend(o.gt.keys());
    }
    gts.sort_unstable();
    gts.dedup();
    if gts.is_empty() {
        return Ok(None);
    }
    let (mut sum, mut successes) = (0.0, 0usize);
    for &g in &gts {
        let chosen = total
            .iter()
            .filter(|((_, g2), _)| *g2 == g)
            .max_by(|a, b| a.1.cmp(b.1).then(b.0.0.cmp(&a.0.0)))
            .map_or(0, |((p, _), _)| *p);
        let ious: Vec<f64> = overlaps
            .iter()
            .filter(|o| o.gt.contains_key(&g))
            .map(|o| if chosen == 0 { 0.0 } else { o.iou(chosen, g) })
            .collect();
        sum += ious.iter().sum::<f64>() / ious.len() as f64;
        successes += usize::from(ious.iter().all(|&iou| iou >= 0.5));
    }
    let n = gts.len();
    Ok(Some(ConsistencyScores {
        t_miou: sum / n as f64,
        t_sr: successes as f64 / n as f64,
        instances: n,
    }))
}

/// Boundary F-score of two id maps `width` wide (Martin et al.'s, as DAVIS scores masks): a
/// pixel is on a boundary where its id differs from its right or lower neighbour's; precision is
/// the share of the predicted boundary within `tolerance` pixels (Chebyshev) of the true one,
/// recall the converse, F their harmonic mean. `None` when neither map has a boundary.
pub fn boundary_f(
    pred: &[u32],
    gt: &[u32],
    width: usize,
    tolerance: usize,
) -> Result<Option<f64>, MetricError> {
    same_len("id maps", pred.len(), gt.len())?;
    let height = pred.len() / width.max(1);
    let edges = |ids: &[u32]| -> Vec<bool> {
        (0..ids.len())
            .map(|i| {
                let (x, y) = (i % width, i / width);
                (x + 1 < width && ids[i] != ids[i + 1])
                    || (y + 1 < height && ids[i] != ids[i + width])
            })
            .collect()
    };
    let (p, g) = (edges(pred), edges(gt));
    let near = |of: &[bool], i: usize| {
        let (x, y) = (i % width, i / width);
        let t = tolerance;
        (y.saturating_sub(t)..(y + t + 1).min(height))
            .any(|yy| (x.saturating_sub(t)..(x + t + 1).min(width)).any(|xx| of[yy * width + xx]))
    };
    let share = |from: &[bool], to: &[bool]| -> Option<f64> {
        let on: Vec<usize> = (0..from.len()).filter(|&i| from[i]).collect();
        (!on.is_empty())
            .then(|| on.iter().filter(|&&i| near(to, i)).count() as f64 / on.len() as f64)
    };
    Ok(match (share(&p, &g), share(&g, &p)) {
        (None, None) => None,
        (Some(precision), Some(recall)) if precision + recall > 0.0 => {
            Some(2.0 * precision * recall / (precision + recall))
        }
        _ => Some(0.0),
    })
}

/// IoU of two masks; `None` when both are empty.
pub fn mask_iou(pred: &[bool], gt: &[bool]) -> Result<Option<f64>, MetricError> {
    same_len("masks", pred.len(), gt.len())?;
    let inter = pred.iter().zip(gt).filter(|(p, g)| **p && **g).count();
    let union = pred.iter().zip(gt).filter(|(p, g)| **p || **g).count();
    Ok((union > 0).then(|| inter as f64 / union as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

    const N: u32 = NO_LABEL;

    #[test]
    fn boundary_f_by_hand() {
        // 6×2 maps split at x = 3 (gt) and x = 4 (pred): one pixel apart.
        let split = |at: usize| -> Vec<u32> { (0..12).map(|i| u32::from(i % 6 >= at)).collect() };
        let (gt, pred) = (split(3), split(4));
        assert_eq!(boundary_f(&pred, &gt, 6, 1).unwrap(), Some(1.0), "within tolerance");
        assert_eq!(boundary_f(&pred, &gt, 6, 0).unwrap(), Some(0.0), "exact: none agree");
        assert_eq!(boundary_f(&gt, &gt, 6, 0).unwrap(), Some(1.0));
        assert_eq!(boundary_f(&[7; 12], &[7; 12], 6, 2).unwrap(), None);
        // A prediction with no boundary where the truth has one scores 0.
        assert_eq!(boundary_f(&[7; 12], &gt, 6, 2).unwrap(), Some(0.0));
    }

    #[test]
    fn semantic_scores_by_hand() {
        // Class 0: gt 3 px, predicted on 2 of them and on 1 class-1 px → IoU 2/4 (ignored
        // pixels do not count). Class 1: gt 2 px, predicted on 1 → IoU 1/2.
        let gt = [0, 0, 0, 1, 1, N, N];
        let pred = [0, 0, 2, 0, 1, 0, 1];
        let s = semantic_scores(&pred, &gt).unwrap().unwrap();
        assert_eq!(s.classes, 2);
        assert!((s.miou - (2.0 / 4.0 + 1.0 / 2.0) / 2.0).abs() < 1e-12, "{s:?}");
        assert!((s.macc - (2.0 / 3.0 + 1.0 / 2.0) / 2.0).abs() < 1e-12, "{s:?}");
        assert_eq!(semantic_scores(&[1, 2], &[N, N]).unwrap(), None);
        assert!(semantic_scores(&[1], &[1, 2]).is_err());
    }

    #[test]
    fn instance_scores_take_the_best_overlapping_prediction() {
        // gt 1 = px 0..4, gt 2 = px 4..6. pred 7 = px 0..3 (IoU 3/4 with gt 1), pred 8 = px
        // 3..6 and 7 (IoU 1/7 with gt 1, 2/4 with gt 2). gt 3 = px 6, predicted nowhere.
        let gt = [1, 1, 1, 1, 2, 2, 3, 0];
        let pred = [7, 7, 7, 8, 8, 8, 0, 8];
        let s = instance_scores(&pred, &gt).unwrap().unwrap();
        let m = &s.matches;
        assert_eq!((m[0].pred, m[1].pred, m[2].pred), (7, 8, 0));
        assert!(
            (m[0].iou - 0.75).abs() < 1e-12 && (m[1].iou - 0.5).abs() < 1e-12 && m[2].iou == 0.0,
            "{m:?}"
        );
        assert!((s.miou - 1.25 / 3.0).abs() < 1e-12);
        assert!((s.acc_25 - 2.0 / 3.0).abs() < 1e-12);
        // Only (7, 1) is above ½; pred 8 (3 of 4 px labelled) is a false positive, gts 2 and 3
        // false negatives: PQ = 0.75 / (1 + ½·1 + ½·2).
        let p = s.panoptic;
        assert_eq!((p.true_positives, p.false_positives, p.false_negatives), (1, 1, 2), "{p:?}");
        assert!((p.pq().unwrap() - 0.75 / 2.5).abs() < 1e-12, "{p:?}");
        assert_eq!(instance_scores(&[1, 2], &[0, 0]).unwrap(), None);
    }

    #[test]
    fn panoptic_quality_charges_an_object_split_in_pieces_where_miou_does_not() {
        // One object of 8 px. Whole: PQ 1. Split 5 + 3: its best piece has IoU 5/8 either way,
        // so mIoU is 5/8 in both, but the split's second piece is a false positive.
        let gt = [1; 8];
        let split = instance_scores(&[4, 4, 4, 4, 4, 9, 9, 9], &gt).unwrap().unwrap();
        assert!((split.miou - 0.625).abs() < 1e-12);
        assert!((split.panoptic.pq().unwrap() - 0.625 / 1.5).abs() < 1e-12, "{:?}", split.panoptic);
        let whole = instance_scores(&[4; 8], &gt).unwrap().unwrap();
        assert_eq!(whole.panoptic.pq(), Some(1.0));
        // A prediction mostly on unlabelled pixels is no false positive; counts of views add.
        let mut both =
            instance_scores(&[4, 4, 5, 5, 5], &[1, 1, 0, 0, 1]).unwrap().unwrap().panoptic;
        assert_eq!(
            (both.true_positives, both.false_positives, both.false_negatives),
            (1, 0, 0),
            "{both:?}"
        );
        both.add(&split.panoptic);
        assert_eq!((both.true_positives, both.false_positives, both.false_negatives), (2, 1, 0));
        assert_eq!(PanopticCounts::default().pq(), None);
        // Pooled: mIoU and Acc@0.25 over both views' instances, PQ over their counts.
        let mut pool = InstancePool::default();
        assert_eq!((pool.miou(), pool.acc_25(), pool.pq()), (None, None, None));
        pool.add(&split);
        pool.add(&whole);
        assert!((pool.miou().unwrap() - (0.625 + 1.0) / 2.0).abs() < 1e-12);
        assert_eq!(pool.acc_25(), Some(1.0));
        assert!((pool.pq().unwrap() - 1.625 / 2.5).abs() < 1e-12);
    }

    #[test]
    fn consistency_picks_one_id_per_instance_across_views() {
        // Instance 1 is id 5 in view A (4 px) and id 6 in view B (2 px): one id for both, 5,
        // which scores 1 in A and 0 in B. Instance 2 is id 9 in both views (IoU 1 and 2/3).
        let (ga, pa) = ([1, 1, 1, 1, 2, 0], [5, 5, 5, 5, 9, 0]);
        let (gb, pb) = ([1, 1, 2, 2, 0, 0], [6, 6, 9, 9, 9, 0]);
        let s = consistency_scores(&[(&pa, &ga), (&pb, &gb)]).unwrap().unwrap();
        assert_eq!(s.instances, 2);
        let expected = ((1.0 + 0.0) / 2.0 + (1.0 + 2.0 / 3.0) / 2.0) / 2.0;
        assert!((s.t_miou - expected).abs() < 1e-12, "{s:?}");
        assert_eq!(s.t_sr, 0.5);
        // A per-view clustering that renames ids between views loses consistency even when each
        // view alone is perfect.
        let per_view_a = instance_scores(&pa, &ga).unwrap().unwrap();
        let per_view_b = instance_scores(&pb, &gb).unwrap().unwrap();
        assert_eq!(per_view_a.matches[0].iou, 1.0);
        assert_eq!(per_view_b.matches[0].iou, 1.0);
        assert_eq!(consistency_scores(&[(&[1], &[0])]).unwrap(), None);
    }

    #[test]
    fn mask_iou_by_hand() {
        assert_eq!(
            mask_iou(&[true, true, false, false], &[true, false, true, false]).unwrap(),
            Some(1.0 / 3.0)
        );
        assert_eq!(mask_iou(&[false], &[false]).unwrap(), None);
    }
}
