//! How a view of a reconstruction is segmented for scoring, in either clustering mode:
//! - 3D (inssplat): the ids clustered once on the Gaussians are rendered into the view; every
//!   view shares the instances, their prototypes and labels.
//! - 2D (the paper's): the view's instance features are rendered and clustered on their own
//!   (HDBSCAN on the feature map), each cluster gets a semantic prototype from the rendered
//!   semantic features and a label; ids mean nothing across views.
//!
//! Either way a pixel's label is its instance's (the instance-grounded aggregation of
//! semantic features); without aggregation (the ablation) every pixel is named from its own
//! rendered semantic feature instead, the instances staying as they are.

use inssplat_proto::{Camera, GaussianScene, INSTANCE_DIM};
use inssplat_raster::masks::NO_LABEL;
use inssplat_raster::masks::{
    FeatureImage, MASK_ALPHA, label_map, render_features, render_instance_ids,
};
use inssplat_understand::cluster::ClusterParams;
use inssplat_understand::cluster::per_view::{FeatureMap, cluster_view};
use inssplat_understand::label::{
    InstancePrototype, LabelMatch, SemanticProjection, assign_labels, semantic_prototypes,
};

use inssplat_pipeline::reconstruct::{Reconstruction, label_table, own_label_scores};

/// Where instances are clustered.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum ClusterMode {
    /// Once, on the Gaussians (inssplat).
    #[value(name = "3d")]
    #[serde(rename = "3d")]
    ThreeD,
    /// On every view's rendered feature map separately (the paper).
    #[value(name = "2d")]
    #[serde(rename = "2d")]
    TwoD,
}

/// One view's segmentation: ids, labels (vocabulary index or `NO_LABEL`) and the prototypes
/// and own-label scores that text queries compare with.
pub struct ViewSegmentation {
    pub ids: Vec<u32>,
    pub labels: Vec<u32>,
    pub prototypes: Vec<InstancePrototype>,
    pub own_scores: Vec<f32>,
}

/// Segments the view seen by `camera`; `texts` are the vocabulary's embeddings.
pub fn segment(
    rec: &Reconstruction,
    camera: &Camera,
    mode: ClusterMode,
    texts: &[[f32; 384]],
    params: &ClusterParams,
) -> Result<ViewSegmentation, String> {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    match mode {
        ClusterMode::ThreeD => {
            let label_of_id = label_table(&rec.instances, &rec.vocabulary);
            let ids =
                render_instance_ids(&rec.scene, camera, label_of_id.len()).map_err(|e| err(&e))?;
            let own_scores = own_label_scores(&rec.prototypes, &rec.instances);
            Ok(ViewSegmentation {
                labels: label_map(&ids, &label_of_id),
                ids,
                prototypes: rec.prototypes.clone(),
                own_scores,
            })
        }
        ClusterMode::TwoD => {
            let image = render_features(&rec.scene, camera).map_err(|e| err(&e))?;
            let clustering = cluster_view(
                &FeatureMap { features: &image.instance, alpha: &image.alpha },
                params,
            )
            .map_err(|e| err(&e))?;
            let (prototypes, matches) = name_pixel_groups(rec, &image, &clustering.ids, texts)?;
            let mut label_of_id = vec![None; clustering.prototypes.len()];
            for (p, m) in prototypes.iter().zip(&matches) {
                label_of_id[p.id as usize - 1] = m.map(|m| m.label);
            }
            let own_scores = matches.iter().map(|m| m.map_or(f32::MIN, |m| m.score)).collect();
            Ok(ViewSegmentation {
                labels: label_map(&clustering.ids, &label_of_id),
                ids: clustering.ids,
                prototypes,
                own_scores,
            })
        }
    }
}

/// Labels of the view seen by `camera` pixel by pixel, each from its own rendered semantic
/// feature (no aggregation over instances); `NO_LABEL` where the accumulated alpha is at most
/// [`MASK_ALPHA`].
pub fn pixel_labels(
    rec: &Reconstruction,
    camera: &Camera,
    texts: &[[f32; 384]],
) -> Result<Vec<u32>, String> {
    let image = render_features(&rec.scene, camera).map_err(|e| e.to_string())?;
    let own: Vec<u32> = image
        .alpha
        .iter()
        .enumerate()
        .map(|(p, &a)| if a > MASK_ALPHA { p as u32 + 1 } else { 0 })
        .collect();
    let (prototypes, matches) = name_pixel_groups(rec, &image, &own, texts)?;
    let mut labels = vec![NO_LABEL; own.len()];
    for (p, m) in prototypes.iter().zip(&matches) {
        if let Some(m) = m {
            labels[p.id as usize - 1] = m.label as u32;
        }
    }
    Ok(labels)
}

/// Semantic prototypes and labels of the pixel groups `ids` (per pixel, 0 = none) of a
/// rendered feature image: pixels as points of a scene, so the 3D mode's prototype code
/// applies unchanged.
fn name_pixel_groups(
    rec: &Reconstruction,
    image: &FeatureImage,
    ids: &[u32],
    texts: &[[f32; 384]],
) -> Result<(Vec<InstancePrototype>, Vec<Option<LabelMatch>>), String> {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let pixels = image.alpha.len();
    let sem_dim = rec.scene.sem_dim;
    let mut points = GaussianScene::with_sem_dim(sem_dim);
    let mut semantic = vec![0.0; sem_dim];
    for (p, &id) in ids.iter().enumerate() {
        for (k, s) in semantic.iter_mut().enumerate() {
            *s = image.semantic[k * pixels + p];
        }
        points.push(inssplat_proto::gaussian::Gaussian {
            mean: [0.0; 3],
            log_scale: [0.0; 3],
            rotation: [1.0, 0.0, 0.0, 0.0],
            logit_opacity: 0.0,
            sh_dc: [0.0; 3],
            confidence: 1.0,
            instance_embedding: [0.0; INSTANCE_DIM],
            semantic: &semantic,
            instance_id: id,
        });
    }
    let projection = SemanticProjection { weight: &rec.sem_proj_weight, bias: &rec.sem_proj_bias };
    let prototypes = semantic_prototypes(&points, &projection).map_err(|e| err(&e))?;
    let matches = assign_labels(&prototypes, texts).map_err(|e| err(&e))?;
    Ok((prototypes, matches))
}
