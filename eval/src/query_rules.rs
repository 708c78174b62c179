//! Text-query scoring: each label present on a scene's target views is asked as a query, and
//! the union of the instances a [`QueryRule`] returns is compared, pooled over the views, with
//! that label's true pixels. `inssplat-eval score --query-rules` scores a grid of rules (minimum
//! score × margin to the best × margin to the instance's own label) in the same pass, for
//! choosing [`QueryRule::default`] on val: the rule is a threshold on cosines, and what names
//! an instance (its features, the shape classifier's weight) moves those cosines.

use inssplat_metrics::segmentation::mask_iou;
use inssplat_raster::masks::NO_LABEL;
use inssplat_raster::masks::ids_mask;
use inssplat_understand::label::{QueryRule, query};
use serde::Serialize;

use super::mean;
use super::views::ViewSegmentation;

/// The rules `--query-rules` scores: min score {0.2, 0.3, 0.4, 0.5} × margin {0.05, 0.1, 0.2,
/// 0.4} × label margin {0, 0.05, 0.15, 0.3, off}.
pub fn grid() -> Vec<QueryRule> {
    let mut rules = Vec::new();
    for min_score in [0.2, 0.3, 0.4, 0.5] {
        for margin in [0.05, 0.1, 0.2, 0.4] {
            for label_margin in [0.0, 0.05, 0.15, 0.3, f32::INFINITY] {
                rules.push(QueryRule { min_score, margin, label_margin });
            }
        }
    }
    rules
}

/// How one rule answered the queries of one scene.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct QueryScores {
    /// Mean over the labels present on the target views of the IoU between the pooled masks
    /// of the instances returned for the label's text and the label's true pixels.
    pub iou: Option<f64>,
    /// Share of the labels the scene does not hold whose query returned an instance in some
    /// target view (a user asking for a lamp in a room without one should get nothing).
    pub false_positive: Option<f64>,
}

/// The scores of one scene under each of `rules`. `gt_labels` are the target views' true
/// vocabulary indices ([`NO_LABEL`] ignored), `absent` the vocabulary indices the scene has no
/// instance of, `texts[label]` each label's text embedding.
pub fn query_scores<T: AsRef<[f32]>>(
    segs: &[ViewSegmentation],
    gt_labels: &[u32],
    absent: &[u32],
    texts: &[T],
    rules: &[QueryRule],
) -> Result<Vec<QueryScores>, String> {
    let present: std::collections::BTreeSet<u32> =
        gt_labels.iter().copied().filter(|l| *l != NO_LABEL).collect();
    // Each present label's true pixels, the same under every rule.
    let wants: Vec<(u32, Vec<bool>)> =
        present.into_iter().map(|l| (l, gt_labels.iter().map(|g| *g == l).collect())).collect();
    let hits = |l: u32, rule: &QueryRule| -> Result<Vec<Vec<u32>>, String> {
        segs.iter()
            .map(|seg| {
                let hits =
                    query(&seg.prototypes, texts[l as usize].as_ref(), &seg.own_scores, rule)
                        .map_err(|e| e.to_string())?;
                Ok(hits.iter().map(|h| h.id).collect())
            })
            .collect()
    };
    rules
        .iter()
        .map(|rule| {
            let mut ious = Vec::new();
            for (l, want) in &wants {
                let per_view = hits(*l, rule)?;
                let got: Vec<bool> = segs
                    .iter()
                    .zip(&per_view)
                    .flat_map(|(seg, ids)| ids_mask(&seg.ids, ids))
                    .collect();
                if let Some(iou) = mask_iou(&got, want).map_err(|e| e.to_string())? {
                    ious.push(iou);
                }
            }
            let answered = absent
                .iter()
                .map(|&l| {
                    Ok(if hits(l, rule)?.iter().any(|ids| !ids.is_empty()) { 1.0 } else { 0.0 })
                })
                .collect::<Result<Vec<f64>, String>>()?;
            Ok(QueryScores { iou: mean(&ious), false_positive: mean(&answered) })
        })
        .collect()
}

/// One rule's means over the scenes of one view count.
#[derive(Debug, Clone, Serialize)]
pub struct RuleRow {
    pub min_score: f32,
    pub margin: f32,
    /// `None`: the own-label test is off.
    pub label_margin: Option<f32>,
    pub query_iou: Option<f64>,
    pub false_positive: Option<f64>,
}

/// Means of each rule of [`grid`] over `per_scene` (each scene's [`query_scores`] under the
/// grid), best query IoU first.
pub fn summarize(per_scene: &[&[QueryScores]]) -> Vec<RuleRow> {
    if per_scene.iter().all(|s| s.is_empty()) {
        return Vec::new();
    }
    let mut rows: Vec<RuleRow> = grid()
        .iter()
        .enumerate()
        .map(|(i, r)| RuleRow {
            min_score: r.min_score,
            margin: r.margin,
            label_margin: r.label_margin.is_finite().then_some(r.label_margin),
            query_iou: mean(&per_scene.iter().filter_map(|s| s.get(i)?.iou).collect::<Vec<_>>()),
            false_positive: mean(
                &per_scene.iter().filter_map(|s| s.get(i)?.false_positive).collect::<Vec<_>>(),
            ),
        })
        .collect();
    rows.sort_by(|a, b| b.query_iou.unwrap_or(0.0).total_cmp(&a.query_iou.unwrap_or(0.0)));
    rows
}

/// The best `top` rows and the default rule's as a markdown table.
pub fn markdown(views: usize, rows: &[RuleRow], top: usize) -> String {
    let d = QueryRule::default();
    let is_default = |r: &RuleRow| {
        r.min_score == d.min_score && r.margin == d.margin && r.label_margin == Some(d.label_margin)
    };
    let mut out = format!(
        "\nQuery rules at {views} views (the best {top} by query IoU, and the default; false positives: share of queries for labels the scene lacks that returned an instance):\n\n| rank | min score | margin | label margin | query IoU | false positives |\n|---|---|---|---|---|---|\n"
    );
    for (rank, r) in rows.iter().enumerate().filter(|(i, r)| *i < top || is_default(r)) {
        out += &format!(
            "| {}{} | {} | {} | {} | {} | {} |\n",
            rank + 1,
            if is_default(r) { " (default)" } else { "" },
            r.min_score,
            r.margin,
            r.label_margin.map_or("off".into(), |m| m.to_string()),
            r.query_iou.map_or("n/a".into(), |v| format!("{:.1}", 100.0 * v)),
            r.false_positive.map_or("n/a".into(), |v| format!("{:.1}%", 100.0 * v)),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use inssplat_understand::label::InstancePrototype;

    /// One view of four pixels: a chair (id 1) on two, a table (id 2) on one, nothing on the
    /// last; the vocabulary is chair, table, lamp, and the scene has no lamp.
    fn view() -> (Vec<ViewSegmentation>, Vec<u32>, Vec<[f32; 3]>) {
        let proto = |id, embedding: [f32; 3]| InstancePrototype {
            id,
            embedding: embedding.to_vec(),
            gaussians: 10,
        };
        let seg = ViewSegmentation {
            ids: vec![1, 1, 2, 0],
            labels: vec![0, 0, 1, NO_LABEL],
            prototypes: vec![proto(1, [1.0, 0.0, 0.0]), proto(2, [0.0, 1.0, 0.0])],
            own_scores: Vec::new(),
        };
        (
            vec![seg],
            vec![0, 0, 1, NO_LABEL],
            vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        )
    }

    #[test]
    fn a_strict_rule_finds_each_label_and_answers_nothing_for_an_absent_one() {
        let (segs, gt, texts) = view();
        let all = QueryRule { min_score: -1.0, margin: f32::INFINITY, label_margin: f32::INFINITY };
        let scores = query_scores(&segs, &gt, &[2], &texts, &[QueryRule::default(), all]).unwrap();
        assert_eq!(scores[0], QueryScores { iou: Some(1.0), false_positive: Some(0.0) });
        // Returning every instance: chair 2/3, table 1/3, and the lamp query answers.
        assert!((scores[1].iou.unwrap() - 0.5).abs() < 1e-9, "{:?}", scores[1]);
        assert_eq!(scores[1].false_positive, Some(1.0));
    }

    #[test]
    fn rules_are_ranked_by_query_iou() {
        let (segs, gt, texts) = view();
        let per_scene = query_scores(&segs, &gt, &[2], &texts, &grid()).unwrap();
        let rows = summarize(&[&per_scene]);
        assert_eq!(rows.len(), grid().len());
        assert!(rows.windows(2).all(|w| w[0].query_iou >= w[1].query_iou));
        assert_eq!(rows[0].query_iou, Some(1.0));
        assert!(markdown(8, &rows, 3).contains("(default)"));
        assert!(summarize(&[&[]]).is_empty());
    }
}
