//! The post-processing chain on the ground truth of synthesized scenes: true depth and
//! cameras, surface normals estimated from that depth, as instance embeddings a noisy one-hot
//! code of the true instance, and as semantic features a noisy one-hot code of the true label
//! whose Φ_sem projection is that label's embedding by the real text model. Back-projection,
//! voxelization (default voxel size), clustering once in 3D and labelling must recover every
//! instance the clustering can see (one covering at least [`MIN_SHARE`] of the pixels:
//! smaller ones fall under HDBSCAN's smallest cluster, 1% of its sample) with its right label,
//! on a few test-split scenes at the model's 128×128: in the context views' masks (each
//! pixel's merged Gaussian's id, what `inssplat reconstruct` writes) at instance mIoU ≥ 0.95;
//! and in masks rendered from the clustered Gaussians at the same cameras, as a novel view is
//! rendered, where the merged Gaussians' footprints blur silhouettes by about a pixel
//! (measured IoU 0.80–0.95 per instance on these scenes' small furniture, hence the lower
//! bounds there).
//! `raster/tests/post_pipeline.rs` runs the same chain on an analytic room of large boxes.
//! Both tests build their inputs with `inssplat_geometry::ideal`.

use inssplat_geometry::backproject::{ViewOutputs, backproject};
use inssplat_geometry::ideal::{ViewPlanes, depth_normals, ideal_view, label_projection};
use inssplat_geometry::voxel::{VoxelParams, voxelize};
use inssplat_metrics::{InstanceMatch, instance_scores};
use inssplat_proto::dataset::{Frame, Scene};
use inssplat_raster::masks::render_instance_ids;
use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};
use inssplat_text::TextEmbedder;
use inssplat_understand::cluster::{ClusterParams, cluster_instances};
use inssplat_understand::label::{SemanticProjection, assign_labels, semantic_prototypes};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Views per scene, and their size.
const VIEWS: usize = 8;
const SIZE: u32 = 128;
/// Uniform noise of ±NOISE on every code entry, as in the analytic-room test.
const NOISE: f32 = 0.15;
/// Share of the pixels (over all views) from which an instance must be recovered.
const MIN_SHARE: f64 = 0.015;
/// Bounds on the recovered instances' IoU (each, and their mean) in the views' own masks, and
/// in masks rendered at the views' cameras.
const CONTEXT_MIN_IOU: f64 = 0.85;
const CONTEXT_MIN_MIOU: f64 = 0.95;
const RENDERED_MIN_IOU: f64 = 0.75;
const RENDERED_MIN_MIOU: f64 = 0.85;

/// Ideal outputs of every frame of `scene`, semantic codes over `vocabulary`.
fn ideal_outputs(scene: &Scene, vocabulary: &[&str], seed: u64) -> Vec<ViewPlanes> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut noise = || rng.random_range(-NOISE..=NOISE);
    // Vocabulary index of each instance id's label (the background, id 0, has none).
    let label_of = |id: u16| {
        let label = scene.label_of(id)?;
        Some(
            vocabulary
                .iter()
                .position(|v| *v == label)
                .expect("every synthesized label is in the vocabulary"),
        )
    };
    scene
        .frames
        .iter()
        .map(|f| {
            let normals = depth_normals(f);
            let ids = f.instances.as_ref().expect("synthesized frames carry instance ids");
            ideal_view(f, |p| normals[p], |p| label_of(ids[p]), vocabulary.len(), &mut noise)
        })
        .collect()
}

/// Instance mIoU of `predicted` against `truth` over the instances covering at least
/// [`MIN_SHARE`] of the pixels, and those instances' matches.
fn sizeable_miou(predicted: &[u32], truth: &[u32]) -> (f64, Vec<InstanceMatch>) {
    let scores = instance_scores(predicted, truth).unwrap().expect("the views show instances");
    let visible: Vec<InstanceMatch> = scores
        .matches
        .into_iter()
        .filter(|m| {
            truth.iter().filter(|&&t| t == m.gt).count() as f64 >= MIN_SHARE * truth.len() as f64
        })
        .collect();
    let miou = visible.iter().map(|m| m.iou).sum::<f64>() / visible.len() as f64;
    (miou, visible)
}

fn ids_of(frames: &[Frame]) -> Vec<u32> {
    frames
        .iter()
        .flat_map(|f| f.instances.as_ref().unwrap().iter().map(|&id| u32::from(id)))
        .collect()
}

fn ious(matches: &[InstanceMatch]) -> String {
    matches
        .iter()
        .map(|m| format!("{}→{} {:.3}", m.gt, m.pred, m.iou))
        .collect::<Vec<_>>()
        .join(", ")
}

#[test]
fn ground_truth_of_synthesized_scenes_recovers_instances_and_labels() {
    let embedder =
        TextEmbedder::from_env().expect("the text model (INSSPLAT_TEXT_MODEL, see scripts/setup)");
    let vocabulary: Vec<&str> = synth::all_labels().into_iter().collect();
    let texts = embedder.embed(&vocabulary).unwrap();
    let (weight, bias) = label_projection(&texts);
    let projection = SemanticProjection { weight: &weight, bias: &bias };

    let mut cfg = SynthConfig::new(Split::Test, Furniture::Primitives);
    (cfg.width, cfg.height, cfg.frames, cfg.objects) = (SIZE, SIZE, (VIEWS, VIEWS), (3, 5));
    for index in [0, 1, 5] {
        let scene = synth::generate_split(index, &cfg).unwrap().scene;
        let planes = ideal_outputs(&scene, &vocabulary, index);
        let views: Vec<ViewOutputs<'_>> =
            planes.iter().zip(&scene.frames).map(|(p, f)| p.outputs(&f.camera)).collect();
        let dense = backproject(&views, vocabulary.len()).unwrap();
        let mut voxelized = voxelize(&dense.scene, &VoxelParams::default()).unwrap();
        let clustering =
            cluster_instances(&mut voxelized.scene, &ClusterParams::default()).unwrap();
        let k = clustering.prototypes.len();
        let compact = &voxelized.scene;

        let truth = ids_of(&scene.frames);
        let (context_miou, visible) =
            sizeable_miou(&dense.to_pixels(&voxelized.input_instance_ids()), &truth);
        let rendered: Vec<u32> = scene
            .frames
            .iter()
            .flat_map(|f| render_instance_ids(compact, &f.camera, k).unwrap())
            .collect();
        let (rendered_miou, rendered_visible) = sizeable_miou(&rendered, &truth);
        eprintln!(
            "scene {index}: {} → {} Gaussians, {k} clusters; views' own masks mIoU {context_miou:.4} ({}); \
             masks rendered at their cameras mIoU {rendered_miou:.4} ({}), over instances covering ≥ {MIN_SHARE}",
            voxelized.report.gaussians_in,
            voxelized.report.gaussians_out,
            ious(&visible),
            ious(&rendered_visible),
        );
        assert!(
            visible.len() >= 3,
            "scene {index}: too few sizeable instances to test ({visible:?})"
        );
        assert!(
            context_miou >= CONTEXT_MIN_MIOU && visible.iter().all(|m| m.iou >= CONTEXT_MIN_IOU),
            "scene {index}, the views' own masks: {visible:?}"
        );
        assert!(
            rendered_miou >= RENDERED_MIN_MIOU
                && rendered_visible.iter().all(|m| m.iou >= RENDERED_MIN_IOU),
            "scene {index}, rendered masks: {rendered_visible:?}"
        );

        let prototypes = semantic_prototypes(compact, &projection).unwrap();
        let labels = assign_labels(&prototypes, &texts).unwrap();
        for m in visible {
            let want = scene.label_of(m.gt as u16).unwrap();
            let at = prototypes.iter().position(|p| p.id == m.pred).unwrap();
            let got = labels[at].expect("a labelled prototype");
            assert_eq!(
                vocabulary[got.label], want,
                "scene {index}: instance {} → id {} ({got:?})",
                m.gt, m.pred
            );
        }
    }
}
