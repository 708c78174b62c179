//! What the labels are on the target views: per true label, the share of its pixels named
//! right and the name it got most often. The semantic mIoU says how far off the names are;
//! this says which way (0.3 called furniture `floor` or `wall`).

use std::collections::BTreeMap;

use inssplat_raster::masks::NO_LABEL;
use serde::Serialize;

/// Pixel counts per (true, predicted) vocabulary index; predicted `NO_LABEL` is unnamed,
/// true `NO_LABEL` pixels are not counted.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Confusion(BTreeMap<(u32, u32), u64>);

/// One true label of [`Confusion::rows`].
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct LabelRow {
    pub label: String,
    pub pixels: u64,
    /// Share of its pixels named with it.
    pub named_right: f64,
    /// The name its pixels got most often (`(unnamed)` where no instance covered them), and
    /// the share that got it.
    pub named_most: String,
    pub named_most_share: f64,
}

impl Confusion {
    /// Counts the pixels of one label map pair (same length, checked by the caller's metric).
    pub fn add(&mut self, pred: &[u32], truth: &[u32]) {
        for (&p, &t) in pred.iter().zip(truth) {
            if t != NO_LABEL {
                *self.0.entry((t, p)).or_default() += 1;
            }
        }
    }

    pub fn merge(&mut self, other: &Confusion) {
        for (&k, &n) in &other.0 {
            *self.0.entry(k).or_default() += n;
        }
    }

    /// One row per true label, the most pixels first.
    pub fn rows(&self, vocabulary: &[String]) -> Vec<LabelRow> {
        let name = |i: u32| {
            vocabulary.get(i as usize).map_or_else(|| "(unnamed)".to_string(), Clone::clone)
        };
        let mut per_truth: BTreeMap<u32, Vec<(u32, u64)>> = BTreeMap::new();
        for (&(t, p), &n) in &self.0 {
            per_truth.entry(t).or_default().push((p, n));
        }
        let mut rows: Vec<LabelRow> = per_truth
            .into_iter()
            .map(|(t, preds)| {
                let pixels: u64 = preds.iter().map(|p| p.1).sum();
                let right = preds.iter().find(|p| p.0 == t).map_or(0, |p| p.1);
                let most = preds
                    .iter()
                    .max_by_key(|p| (p.1, std::cmp::Reverse(p.0)))
                    .copied()
                    .unwrap_or((NO_LABEL, 0));
                LabelRow {
                    label: name(t),
                    pixels,
                    named_right: right as f64 / pixels as f64,
                    named_most: name(most.0),
                    named_most_share: most.1 as f64 / pixels as f64,
                }
            })
            .collect();
        rows.sort_by(|a, b| b.pixels.cmp(&a.pixels).then_with(|| a.label.cmp(&b.label)));
        rows
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_give_each_true_labels_right_share_and_most_common_name() {
        let vocabulary: Vec<String> = ["chair", "floor", "lamp"].map(String::from).to_vec();
        let mut a = Confusion::default();
        // chair: 3 px, 1 right, 2 called floor; lamp: 1 px unnamed; one unlabelled pixel.
        a.add(&[0, 1, 1, NO_LABEL, 2], &[0, 0, 0, 2, NO_LABEL]);
        let mut b = Confusion::default();
        b.add(&[2, 2], &[2, 2]);
        a.merge(&b);
        let rows = a.rows(&vocabulary);
        let row = |label: &str, pixels, named_right, named_most: &str, named_most_share| LabelRow {
            label: label.into(),
            pixels,
            named_right,
            named_most: named_most.into(),
            named_most_share,
        };
        assert_eq!(
            rows,
            [
                row("chair", 3, 1.0 / 3.0, "floor", 2.0 / 3.0),
                row("lamp", 3, 2.0 / 3.0, "lamp", 2.0 / 3.0)
            ]
        );
    }
}
