//! The whole post-processing chain on ground truth: an analytic room's true depth and
//! cameras, noisy one-hot instance embeddings and semantic codes go through back-projection,
//! voxelization (default voxel size), 3D clustering, input-view masks and labelling; the
//! instances must come back (instance mIoU ≥ 0.95 over the context views, every view
//! agreeing) with the right labels (semantic mIoU ≥ 0.95), and a text query must find both
//! chairs.

use inssplat_geometry::analytic_room::{
    SEM_DIM, VOCABULARY, ideal_outputs, label_index, render_scene, ring_cameras, text_space,
};
use inssplat_geometry::backproject::{ViewOutputs, backproject};
use inssplat_geometry::voxel::{VoxelParams, voxelize};
use inssplat_metrics::{consistency_scores, instance_scores, mask_iou, semantic_scores};
use inssplat_raster::masks::NO_LABEL;
use inssplat_raster::masks::{ids_mask, label_map};
use inssplat_understand::cluster::{ClusterParams, cluster_instances};
use inssplat_understand::label::{
    QueryRule, SemanticProjection, assign_labels, query, semantic_prototypes,
};

#[test]
fn ground_truth_inputs_recover_instances_and_labels() {
    let cameras = ring_cameras(8, 128);
    let scene = render_scene(&cameras);
    let planes = ideal_outputs(&scene, 0.15, 7);
    let views: Vec<ViewOutputs<'_>> =
        planes.iter().zip(&cameras).map(|(p, camera)| p.outputs(camera)).collect();
    let dense = backproject(&views, SEM_DIM).unwrap();
    let mut voxelized = voxelize(&dense.scene, &VoxelParams::default()).unwrap();
    let report = voxelized.report;
    assert!(report.gaussians_out * 4 <= 8 * 128 * 128, "{report:?}");
    let clustering = cluster_instances(&mut voxelized.scene, &ClusterParams::default()).unwrap();
    let k = clustering.prototypes.len();
    // Four boxes and the floor.
    assert_eq!(k, 5, "{clustering:?}");

    let predicted: Vec<Vec<u32>> = dense
        .to_pixels(&voxelized.input_instance_ids())
        .chunks_exact(128 * 128)
        .map(<[u32]>::to_vec)
        .collect();
    let compact = &voxelized.scene;
    let truth: Vec<Vec<u32>> = scene
        .frames
        .iter()
        .map(|f| f.instances.as_ref().unwrap().iter().map(|&i| u32::from(i)).collect())
        .collect();
    let scores = instance_scores(&predicted.concat(), &truth.concat()).unwrap().unwrap();
    assert!(scores.miou >= 0.95, "{scores:?}");
    let pairs: Vec<(&[u32], &[u32])> =
        predicted.iter().zip(&truth).map(|(p, t)| (p.as_slice(), t.as_slice())).collect();
    let consistency = consistency_scores(&pairs).unwrap().unwrap();
    assert!(consistency.t_miou >= 0.9 && consistency.t_sr == 1.0, "{consistency:?}");

    let text = text_space(11);
    let proj = SemanticProjection { weight: &text.weight, bias: &text.bias };
    let prototypes = semantic_prototypes(compact, &proj).unwrap();
    let labels = assign_labels(&prototypes, &text.vocabulary).unwrap();
    for m in &scores.matches {
        let truth_label = scene.label_of(m.gt as u16).unwrap();
        let at = prototypes.iter().position(|p| p.id == m.pred).unwrap();
        let got = labels[at].unwrap();
        assert_eq!(
            VOCABULARY[got.label], truth_label,
            "instance {} → id {} ({:?})",
            m.gt, m.pred, got
        );
        assert!(got.score > 0.8, "{got:?}");
    }

    // Semantic maps: each predicted instance painted with its label, against the true labels
    // (background ignored).
    let mut label_of_id = vec![None; k];
    for (p, l) in prototypes.iter().zip(&labels) {
        label_of_id[p.id as usize - 1] = l.map(|m| m.label);
    }
    let predicted_labels = label_map(&predicted.concat(), &label_of_id);
    let true_labels: Vec<u32> = truth
        .concat()
        .iter()
        .map(|&id| {
            if id == 0 { NO_LABEL } else { label_index(scene.label_of(id as u16).unwrap()) as u32 }
        })
        .collect();
    let semantic = semantic_scores(&predicted_labels, &true_labels).unwrap().unwrap();
    assert!(semantic.miou >= 0.95 && semantic.classes == 3, "{semantic:?}");
    eprintln!(
        "{} → {} Gaussians, {k} instances, instance mIoU {:.4}, T-mIoU {:.4}, T-SR@0.5 {:.2}, semantic mIoU {:.4}",
        report.gaussians_in,
        report.gaussians_out,
        scores.miou,
        consistency.t_miou,
        consistency.t_sr,
        semantic.miou
    );

    // Query "chair": exactly the two chairs' ids; the mask matches the chairs' union.
    let hits =
        query(&prototypes, &text.vocabulary[label_index("chair")], &[], &QueryRule::default())
            .unwrap();
    let mut hit_ids: Vec<u32> = hits.iter().map(|h| h.id).collect();
    hit_ids.sort_unstable();
    let mut chair_ids: Vec<u32> =
        scores.matches.iter().filter(|m| m.gt == 2 || m.gt == 3).map(|m| m.pred).collect();
    chair_ids.sort_unstable();
    assert_eq!(hit_ids, chair_ids);
    let iou =
        mask_iou(&ids_mask(&predicted.concat(), &hit_ids), &ids_mask(&truth.concat(), &[2, 3]))
            .unwrap()
            .unwrap();
    assert!(iou >= 0.95, "{iou}");
}
