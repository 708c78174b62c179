//! The evaluation's report as markdown: the table per view count, the context views' instance
//! and depth breakdowns, the labels named at the view count nearest 8, the query rules, the
//! robustness rows, the worst scenes and the protocol line; and the sweep's table.

use super::{ClusterMode, Report, query_rules, sweep};

/// The sweep as a markdown table.
pub fn sweep_markdown(points: &[sweep::SweepPoint]) -> String {
    let mut out = String::from(
        "| views | voxel | HDBSCAN samples | s/scene | inst mIoU | PSNR | Pareto (mIoU / PSNR) |\n|---|---|---|---|---|---|---|\n",
    );
    for p in points {
        out += &format!(
            "| {} | 1/{:.0} of extent | {} | {:.2} | {} | {} | {} / {} |\n",
            p.knobs.views,
            1.0 / p.knobs.voxel_fraction,
            p.knobs.cluster_samples,
            p.seconds,
            p.instance_miou.map_or("n/a".into(), |v| format!("{:.1}", 100.0 * v)),
            p.psnr.map_or("n/a".into(), |v| format!("{v:.2}")),
            if p.pareto_instance { "yes" } else { "no" },
            if p.pareto_psnr { "yes" } else { "no" },
        );
    }
    out
}

/// Percent with one decimal, for IoU-like metrics.
fn pct(v: Option<&(f64, usize)>) -> String {
    v.map_or("n/a".into(), |(m, _)| format!("{:.1}", 100.0 * m))
}

fn num(v: Option<&(f64, usize)>, digits: usize) -> String {
    v.map_or("n/a".into(), |(m, _)| format!("{m:.digits$}"))
}

/// The markdown table of a report.
pub fn markdown(r: &Report) -> String {
    let hdbscan = format!(
        "HDBSCAN smallest cluster share {}, min_samples {}, joined at cosine ≥ {}",
        r.min_cluster_share, r.min_samples, r.min_cosine
    );
    let mode = match r.cluster {
        ClusterMode::ThreeD => format!(
            "instances clustered once in 3D (position weight {}; {hdbscan})",
            r.position_weight
        ),
        ClusterMode::TwoD => {
            format!("instances clustered per view in 2D (the paper's mode; {hdbscan})")
        }
    };
    let mut notes = String::new();
    if r.switches.known_poses {
        notes += " Cameras: the true context poses (--known-poses), not the camera head.";
    }
    if r.switches.known_depth {
        notes += " Depth: the true context depth (--known-depth), not the depth head.";
    }
    if r.switches.known_names {
        notes += " Names: each found instance named with its true label (--known-names), not the classifier.";
    }
    if r.switches.no_aggregation {
        notes += " Labels per pixel, no instance-grounded aggregation (--no-aggregation).";
    }
    if r.switches.no_fill {
        notes += " Target views scored on their raw renders (--no-fill).";
    }
    let mut out = format!(
        "Model `{}`, {} scenes from `{}`, {mode}.{notes}\n\n",
        r.model_version,
        r.scenes.len() / r.summaries.len().max(1),
        r.data
    );
    out += "| views | sem mIoU | sem mAcc | inst mIoU | inst Acc@0.25 | inst PQ | query IoU | T-mIoU | T-SR@0.5 | PSNR | SSIM | depth AbsRel | rot err ° | trans err | s/scene | Gaussians kept |\n";
    out += "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    for s in &r.summaries {
        let m = |k: &str| s.metrics.get(k);
        out += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} | {:.0} |\n",
            s.views,
            pct(m("semantic_miou")),
            pct(m("semantic_macc")),
            pct(m("instance_miou")),
            pct(m("instance_acc25")),
            pct(m("instance_pq")),
            pct(m("query_iou")),
            pct(m("t_miou")),
            pct(m("t_sr50")),
            num(m("psnr"), 2),
            num(m("ssim"), 3),
            num(m("depth_abs_rel"), 3),
            num(m("rotation_deg"), 2),
            num(m("translation"), 3),
            s.seconds_median,
            s.gaussians_kept_mean
        );
    }
    if r.summaries.iter().any(|s| s.metrics.contains_key("context_ceiling_miou")) {
        out += "\nInstances on the context views (what limits instance mIoU: the embeddings when the ceiling is low, the clustering when it lies far above the clustering):\n\n";
        out += "| views | instances found | true instances | inst mIoU, clustering | inst mIoU, nearest true prototype (ceiling) |\n|---|---|---|---|---|\n";
        for s in &r.summaries {
            let m = |k: &str| s.metrics.get(k);
            out += &format!(
                "| {} | {} | {} | {} | {} |\n",
                s.views,
                num(m("instances_found"), 1),
                num(m("instances_true"), 1),
                pct(m("context_instance_miou")),
                pct(m("context_ceiling_miou"))
            );
        }
    }
    if r.summaries.iter().any(|s| s.metrics.contains_key("depth_abs_rel_objects")) {
        out += "\nDepth AbsRel on the context views, at the whole views' median scale, by what the pixels show:\n\n";
        out += "| views | all pixels | objects | room shell |\n|---|---|---|---|\n";
        for s in &r.summaries {
            let m = |k: &str| s.metrics.get(k);
            out += &format!(
                "| {} | {} | {} | {} |\n",
                s.views,
                num(m("depth_abs_rel"), 3),
                num(m("depth_abs_rel_objects"), 3),
                num(m("depth_abs_rel_shell"), 3)
            );
        }
    }
    // The names at the view count nearest the paper's headline 8.
    if let Some(s) =
        r.summaries.iter().filter(|s| !s.labels.is_empty()).min_by_key(|s| s.views.abs_diff(8))
    {
        out += &format!(
            "\nLabels on the target views at {} views (the 12 with the most pixels):\n\n",
            s.views
        );
        out += "| true label | pixels | named right | named most often | share |\n|---|---|---|---|---|\n";
        for row in s.labels.iter().take(12) {
            out += &format!(
                "| {} | {} | {:.1}% | {} | {:.1}% |\n",
                row.label,
                row.pixels,
                100.0 * row.named_right,
                row.named_most,
                100.0 * row.named_most_share
            );
        }
    }
    for s in r.summaries.iter().filter(|s| !s.query_rules.is_empty()) {
        out += &query_rules::markdown(s.views, &s.query_rules, 10);
    }
    if !r.robustness.is_empty() {
        let views = r.robustness[0].summary.views;
        out += &format!(
            "\nRobustness at {views} views:\n\n| perturbation | strength | unit | inst mIoU | sem mIoU | T-mIoU | query IoU | PSNR | depth AbsRel | scenes |\n|---|---|---|---|---|---|---|---|---|---|\n"
        );
        for row in &r.robustness {
            let m = |k: &str| row.summary.metrics.get(k);
            out += &format!(
                "| {:?} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                row.kind,
                row.strength,
                row.kind.unit(),
                pct(m("instance_miou")),
                pct(m("semantic_miou")),
                pct(m("t_miou")),
                pct(m("query_iou")),
                num(m("psnr"), 2),
                num(m("depth_abs_rel"), 3),
                row.summary.scenes
            );
        }
    }
    if !r.failures.is_empty() {
        out += "\nWorst scenes (instance mIoU):\n\n";
        for f in &r.failures {
            out += &format!(
                "- {}: instance mIoU {}, semantic mIoU {}{}\n",
                f.scene,
                f.instance_miou.map_or("n/a".into(), |v| format!("{:.1}", 100.0 * v)),
                f.semantic_miou.map_or("n/a".into(), |v| format!("{:.1}", 100.0 * v)),
                f.preview.as_ref().map_or(String::new(), |p| format!(", preview {}", p.display()))
            );
        }
    }
    out += &format!("\nProtocol: {}.\n", r.protocol);
    out
}
