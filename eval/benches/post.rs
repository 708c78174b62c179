//! Post-processing benchmark: back-project, voxelize, cluster (once in 3D, and the paper's
//! per-view 2D mode on rendered instance feature maps, measured in the same run), label and
//! the input views' masks (each pixel's merged Gaussian's id), for 2, 4, 8 and 16 views of 128×128
//! of the analytic test room (evenly
//! spaced views out of one ring of 16). Prints per-stage medians, Gaussians kept vs pixels
//! in, mask quality of both clustering modes against the ground truth (mean per-view
//! instance mIoU, and T-mIoU across views), and the contract checks: 3D clustering at 16 views ≤
//! 1.2× that at 8, Gaussians kept
//! ≤ 25% of input pixels, 16 views keeping ≤ 1.5× the Gaussians of 8.
//!
//! `cargo bench -p inssplat-raster --bench post`

use std::time::{Duration, Instant};

use inssplat_geometry::analytic_room::{
    SEM_DIM, ideal_outputs, render_scene, ring_cameras, text_space,
};
use inssplat_geometry::backproject::{ViewOutputs, backproject};
use inssplat_geometry::voxel::{VoxelParams, Voxelized, voxelize};
use inssplat_metrics::{consistency_scores, instance_scores};
use inssplat_proto::INSTANCE_DIM;
use inssplat_raster::render::{Splats, render};
use inssplat_understand::cluster::per_view::{FeatureMap, cluster_views};
use inssplat_understand::cluster::{ClusterParams, cluster_instances};
use inssplat_understand::label::{SemanticProjection, assign_labels, semantic_prototypes};

const SIZE: u32 = 128;
const REPEATS: usize = 5;

/// Median wall time of `REPEATS` runs of `f`, and its last result.
fn time<T>(mut f: impl FnMut() -> T) -> (Duration, T) {
    let mut times = Vec::with_capacity(REPEATS);
    let mut out = None;
    for _ in 0..REPEATS {
        let start = Instant::now();
        out = Some(f());
        times.push(start.elapsed());
    }
    times.sort();
    (times[REPEATS / 2], out.expect("at least one run"))
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

struct Row {
    views: usize,
    pixels: usize,
    kept: usize,
    backproject: Duration,
    voxelize: Duration,
    cluster_3d: Duration,
    cluster_2d: Duration,
    label: Duration,
    masks: Duration,
    instances: usize,
    quality_3d: (f64, f64),
    quality_2d: (f64, f64),
}

/// Mean over views of the per-view instance mIoU, and T-mIoU across the views.
fn quality(predicted: &[&[u32]], truth: &[Vec<u32>]) -> (f64, f64) {
    let per_view: f64 = predicted
        .iter()
        .zip(truth)
        .map(|(p, t)| instance_scores(p, t).expect("same size").map_or(0.0, |s| s.miou))
        .sum::<f64>()
        / predicted.len() as f64;
    let pairs: Vec<(&[u32], &[u32])> =
        predicted.iter().zip(truth).map(|(p, t)| (*p, t.as_slice())).collect();
    (per_view, consistency_scores(&pairs).expect("same size").map_or(0.0, |s| s.t_miou))
}

fn main() {
    let ring = ring_cameras(16, SIZE);
    let scene = render_scene(&ring);
    let planes = ideal_outputs(&scene, 0.15, 7);
    let text = text_space(11);
    let proj = SemanticProjection { weight: &text.weight, bias: &text.bias };
    let params = ClusterParams::default();
    let mut rows = Vec::new();
    for views in [2, 4, 8, 16] {
        let picked: Vec<usize> = (0..views).map(|i| i * 16 / views).collect();
        let inputs: Vec<ViewOutputs<'_>> =
            picked.iter().map(|&i| planes[i].outputs(&ring[i])).collect();
        let (t_bp, dense) = time(|| backproject(&inputs, SEM_DIM).expect("back-projection"));
        let (t_vox, voxelized) =
            time(|| voxelize(&dense.scene, &VoxelParams::default()).expect("voxelization"));
        let compact = voxelized.scene.clone();
        let (t_c3, (clustered_scene, k)) = time(|| {
            let mut s = compact.clone();
            let c = cluster_instances(&mut s, &params).expect("3D clustering");
            (s, c.prototypes.len())
        });
        let clustered = Voxelized { scene: clustered_scene, ..voxelized };
        let (t_label, _) = time(|| {
            let protos = semantic_prototypes(&clustered.scene, &proj).expect("prototypes");
            assign_labels(&protos, &text.vocabulary).expect("labels")
        });
        let pixels = (SIZE * SIZE) as usize;
        let (t_masks, masks) = time(|| {
            dense
                .to_pixels(&clustered.input_instance_ids())
                .chunks_exact(pixels)
                .map(<[u32]>::to_vec)
                .collect::<Vec<_>>()
        });
        // The paper's mode clusters each view's rendered instance feature map.
        let embeddings: Vec<f32> = compact.instance_embedding.iter().flatten().copied().collect();
        let splats = Splats {
            means: &compact.means,
            log_scales: &compact.log_scales,
            rotations: &compact.rotations,
            logit_opacity: &compact.logit_opacity,
            features: &embeddings,
            channels: INSTANCE_DIM,
        };
        let rendered: Vec<_> = picked
            .iter()
            .map(|&i| render(&splats, &ring[i], &[0.0; INSTANCE_DIM]).expect("feature render").0)
            .collect();
        let maps: Vec<FeatureMap<'_>> = rendered
            .iter()
            .map(|im| FeatureMap { features: &im.features, alpha: &im.alpha })
            .collect();
        let (t_c2, per_view) = time(|| cluster_views(&maps, &params).expect("2D clustering"));
        let truth: Vec<Vec<u32>> = picked
            .iter()
            .map(|&i| {
                scene.frames[i]
                    .instances
                    .as_ref()
                    .expect("instances")
                    .iter()
                    .map(|&id| u32::from(id))
                    .collect()
            })
            .collect();
        let per_view_ids: Vec<&[u32]> = per_view.iter().map(|c| c.ids.as_slice()).collect();
        let mask_ids: Vec<&[u32]> = masks.iter().map(Vec::as_slice).collect();
        rows.push(Row {
            views,
            pixels: views * (SIZE * SIZE) as usize,
            kept: compact.len(),
            backproject: t_bp,
            voxelize: t_vox,
            cluster_3d: t_c3,
            cluster_2d: t_c2,
            label: t_label,
            masks: t_masks,
            instances: k,
            quality_3d: quality(&mask_ids, &truth),
            quality_2d: quality(&per_view_ids, &truth),
        });
    }

    println!(
        "post-processing, {SIZE}×{SIZE} views, median of {REPEATS} runs, {} rayon threads",
        rayon::current_num_threads()
    );
    println!(
        "| views | pixels in | Gaussians kept | kept/pixels | back-project ms | voxelize ms | cluster 3D ms | cluster 2D per-view ms | label ms | masks ms | instances | 3D: view mIoU / T-mIoU | 2D: view mIoU / T-mIoU |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in &rows {
        println!(
            "| {} | {} | {} | {:.1}% | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {} | {:.3} / {:.3} | {:.3} / {:.3} |",
            r.views,
            r.pixels,
            r.kept,
            100.0 * r.kept as f64 / r.pixels as f64,
            ms(r.backproject),
            ms(r.voxelize),
            ms(r.cluster_3d),
            ms(r.cluster_2d),
            ms(r.label),
            ms(r.masks),
            r.instances,
            r.quality_3d.0,
            r.quality_3d.1,
            r.quality_2d.0,
            r.quality_2d.1
        );
    }
    let (r8, r16) = (&rows[2], &rows[3]);
    let check = |ok: bool| if ok { "PASS" } else { "FAIL" };
    let c_ratio = ms(r16.cluster_3d) / ms(r8.cluster_3d);
    let c2_ratio = ms(r16.cluster_2d) / ms(r8.cluster_2d);
    println!(
        "cluster 3D 16/8 views: {c_ratio:.2}× (≤ 1.2×: {}); 2D per-view mode 16/8: {c2_ratio:.2}×",
        check(c_ratio <= 1.2)
    );
    let worst = rows.iter().map(|r| r.kept as f64 / r.pixels as f64).fold(0.0, f64::max);
    println!(
        "Gaussians kept ≤ 25% of pixels at every view count: worst {:.1}% ({})",
        100.0 * worst,
        check(worst <= 0.25)
    );
    let k_ratio = r16.kept as f64 / r8.kept as f64;
    println!("Gaussians kept 16/8 views: {k_ratio:.2}× (≤ 1.5×: {})", check(k_ratio <= 1.5));
}
