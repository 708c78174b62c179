//! Instance masks by rendering: every Gaussian carries its instance id, the rasterizer
//! composites the ids in one pass ([`render_ids_any`]), and each pixel takes the id of
//! largest weight where the accumulated alpha exceeds 0.5 (else 0). Because ids live on the
//! Gaussians, masks of any view, context or novel, agree by construction. Also the small maps
//! built from an id map: a label map and the mask of a set of ids (a text query's answer);
//! and the scene's colour image from any camera (novel-view RGB for evaluation); and a new
//! view's maps with what no Gaussian covers filled ([`crate::fill`]).

use inssplat_proto::gaussian::LengthMismatch;
use inssplat_proto::{Camera, GaussianScene};

use crate::fill::{fill_colour, nearest_covered};
use crate::render::{Backend, GpuRenderer, RenderError, Splats, render, render_ids_any};

/// Label-map value for "no label" (background, unlabelled instance).
pub const NO_LABEL: u32 = u32::MAX;

#[derive(Debug, thiserror::Error)]
pub enum MaskError {
    #[error("invalid scene: {0}")]
    Scene(#[from] LengthMismatch),
    #[error("rendering the instance channels: {0}")]
    Render(#[from] RenderError),
    #[error(
        "the photo has {got} values where the camera's size needs {expected} (three planes of width × height)"
    )]
    PhotoSize { expected: usize, got: usize },
}

/// Alpha above which a pixel belongs to some instance.
pub const MASK_ALPHA: f32 = 0.5;

/// The scene's Gaussians with `features` (`channels` per Gaussian) as the rasterizer's input.
pub fn splats<'a>(scene: &'a GaussianScene, features: &'a [f32], channels: usize) -> Splats<'a> {
    Splats {
        means: &scene.means,
        log_scales: &scene.log_scales,
        rotations: &scene.rotations,
        logit_opacity: &scene.logit_opacity,
        features,
        channels,
    }
}

/// Renders `scene.instance_id` (ids 1..=`instances`; others count as none) seen by `camera`
/// into an id map, row-major `[H][W]`, 0 = none, on the CPU.
pub fn render_instance_ids(
    scene: &GaussianScene,
    camera: &Camera,
    instances: usize,
) -> Result<Vec<u32>, MaskError> {
    render_instance_ids_on(None, scene, camera, instances).map(|(ids, _)| ids)
}

/// [`render_instance_ids`] on `gpu` when given and working (else the CPU); says which ran.
pub fn render_instance_ids_on(
    gpu: Option<&GpuRenderer>,
    scene: &GaussianScene,
    camera: &Camera,
    instances: usize,
) -> Result<(Vec<u32>, Backend), MaskError> {
    scene.validate()?;
    let pixels = camera.intrinsics.width as usize * camera.intrinsics.height as usize;
    if instances == 0 {
        return Ok((vec![0; pixels], Backend::Cpu));
    }
    // Ids past the instance count are no instance.
    let ids: Vec<u32> =
        scene.instance_id.iter().map(|&id| if id as usize <= instances { id } else { 0 }).collect();
    let (image, backend) = render_ids_any(gpu, &splats(scene, &[], 0), &ids, camera, MASK_ALPHA)?;
    Ok((image.ids, backend))
}

/// The scene's colours (SH degree 0) seen by `camera` over black: planar `[3][H][W]`, not
/// clamped (a metric clamps if it needs to). With `fill`, what no Gaussian covers takes the
/// colours around it ([`fill_colour`] on the pixels without an instance): a new view's render.
pub fn render_colour(
    scene: &GaussianScene,
    camera: &Camera,
    fill: bool,
) -> Result<Vec<f32>, MaskError> {
    scene.validate()?;
    let (image, _) = render(&splats(scene, &colours(scene), 3), camera, &[0.0; 3])?;
    Ok(match fill {
        true => fill_colour(
            &image.features,
            &image.alpha,
            image.width as usize,
            image.height as usize,
            MASK_ALPHA,
        ),
        false => image.features,
    })
}

/// Every pixel of a view's id map without an instance (0), in `ids` and in its label map
/// `labels` alike where given, takes the nearest one's id and label ([`nearest_covered`]).
pub fn fill_uncovered(ids: &mut [u32], labels: Option<&mut [u32]>, width: usize, height: usize) {
    let source = nearest_covered(&ids.iter().map(|&i| i != 0).collect::<Vec<_>>(), width, height);
    let read = |map: &mut [u32]| {
        let own = map.to_vec();
        map.iter_mut().zip(&source).for_each(|(v, &s)| *v = own[s]);
    };
    read(ids);
    if let Some(labels) = labels {
        read(labels);
    }
}

/// The scene's SH-DC colours as RGB, row-major per Gaussian.
pub fn colours(scene: &GaussianScene) -> Vec<f32> {
    scene.sh_dc.iter().flat_map(|c| c.map(inssplat_proto::gaussian::sh_dc_to_rgb)).collect()
}

/// A scene's instance embedding and semantic feature rendered into one view.
#[derive(Debug, Clone)]
pub struct FeatureImage {
    /// `[8][H][W]`.
    pub instance: Vec<f32>,
    /// `[d_s][H][W]`.
    pub semantic: Vec<f32>,
    /// `[H][W]` accumulated alpha.
    pub alpha: Vec<f32>,
}

/// Renders the scene's instance embeddings and semantic features seen by `camera` (one pass,
/// 8 + d_s channels), for clustering a view in 2D as the paper does.
pub fn render_features(scene: &GaussianScene, camera: &Camera) -> Result<FeatureImage, MaskError> {
    scene.validate()?;
    let (e, ds) = (inssplat_proto::INSTANCE_DIM, scene.sem_dim);
    let channels = e + ds;
    let mut features = Vec::with_capacity(scene.len() * channels);
    for i in 0..scene.len() {
        features.extend_from_slice(&scene.instance_embedding[i]);
        features.extend_from_slice(scene.semantic_of(i));
    }
    let (mut image, _) = render(&splats(scene, &features, channels), camera, &vec![0.0; channels])?;
    let pixels = camera.intrinsics.width as usize * camera.intrinsics.height as usize;
    let semantic = image.features.split_off(e * pixels);
    Ok(FeatureImage { instance: image.features, semantic, alpha: image.alpha })
}

/// Label map of an id map: `label_of_id[id − 1]` per pixel, [`NO_LABEL`] for id 0, ids past
/// the table and unlabelled ids.
pub fn label_map(ids: &[u32], label_of_id: &[Option<usize>]) -> Vec<u32> {
    ids.iter()
        .map(|&id| {
            let label =
                (id as usize).checked_sub(1).and_then(|k| label_of_id.get(k).copied().flatten());
            label.map_or(NO_LABEL, |l| l as u32)
        })
        .collect()
}

/// Mask of the pixels whose id is one of `wanted`.
pub fn ids_mask(ids: &[u32], wanted: &[u32]) -> Vec<bool> {
    ids.iter().map(|id| *id != 0 && wanted.contains(id)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Quat, Vec3};
    use inssplat_proto::Intrinsics;
    use inssplat_proto::gaussian::{Gaussian, logit};

    #[test]
    fn label_map_and_query_mask_follow_the_ids() {
        let ids = [0, 1, 2, 3, 2, 9];
        assert_eq!(
            label_map(&ids, &[Some(4), None, Some(0)]),
            vec![NO_LABEL, 4, NO_LABEL, 0, NO_LABEL, NO_LABEL]
        );
        assert_eq!(ids_mask(&ids, &[2, 9, 0]), vec![false, false, true, false, true, true]);
    }

    #[test]
    fn two_opaque_discs_render_to_their_ids() {
        // Camera at the origin looking down +z; 32×32, f = 32. Disc 1 covers the left half
        // at depth 2, disc 2 the right half at depth 3.
        let k = Intrinsics { fx: 32.0, fy: 32.0, cx: 16.0, cy: 16.0, width: 32, height: 32 };
        let cam = Camera { intrinsics: k, rotation: Quat::IDENTITY, translation: Vec3::ZERO };
        let mut s = GaussianScene::with_sem_dim(0);
        let mut add = |mean: [f32; 3], scale: f32, id: u32| {
            s.push(Gaussian {
                mean,
                log_scale: [scale.ln(), scale.ln(), -6.0],
                rotation: [1.0, 0.0, 0.0, 0.0],
                logit_opacity: logit(0.99),
                sh_dc: [0.0; 3],
                confidence: 1.0,
                instance_embedding: [0.0; 8],
                semantic: &[],
                instance_id: id,
            })
        };
        for i in 0..8 {
            for j in 0..16 {
                let (x, y) = (-1.0 + 0.125 * i as f32, -1.0 + 0.125 * j as f32);
                add([x + 0.0625, y + 0.0625, 2.0], 0.08, 1);
                add([1.5 * (x + 1.0 + 0.0625), 1.5 * (y + 0.0625), 3.0], 0.12, 2);
            }
        }
        let ids = render_instance_ids(&s, &cam, 2).unwrap();
        assert_eq!(ids[16 * 32 + 6], 1);
        assert_eq!(ids[16 * 32 + 25], 2);
        let left = (0..32 * 32).filter(|&p| p % 32 < 14 && (4..28).contains(&(p / 32)));
        assert!(
            left.clone().all(|p| ids[p] == 1),
            "{:?}",
            left.map(|p| ids[p]).collect::<Vec<_>>()
        );
        assert!(
            (0..32 * 32)
                .filter(|&p| p % 32 > 18 && (4..28).contains(&(p / 32)))
                .all(|p| ids[p] == 2)
        );
        assert_eq!(render_instance_ids(&s, &cam, 0).unwrap(), vec![0; 32 * 32]);
    }
}
