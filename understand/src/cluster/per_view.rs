//! The paper's clustering mode, kept for comparison: HDBSCAN runs on each view's rendered
//! instance feature map separately (pixels with alpha > 0.5, the same bounded subsample and
//! nearest-prototype assignment as the 3D mode, weights = alpha). Ids are local to a view, so
//! nothing makes two views agree, and the cost grows with the number of views.

use inssplat_proto::INSTANCE_DIM;
use rayon::prelude::*;

use inssplat_proto::gaussian::unit;

use super::{ClusterError, ClusterParams, Clustering, Embedding, cluster_points};

/// One view's rendered instance features `[8][H][W]` and alpha `[H][W]`.
#[derive(Debug, Clone, Copy)]
pub struct FeatureMap<'a> {
    pub features: &'a [f32],
    pub alpha: &'a [f32],
}

/// Clusters one view: an id per pixel (0 where alpha ≤ 0.5 or no prototype is close).
pub fn cluster_view(
    map: &FeatureMap<'_>,
    params: &ClusterParams,
) -> Result<Clustering, ClusterError> {
    let pixels = map.alpha.len();
    if map.features.len() != INSTANCE_DIM * pixels {
        return Err(ClusterError::Shape {
            actual: map.features.len(),
            expected: INSTANCE_DIM * pixels,
            channels: INSTANCE_DIM,
            pixels,
        });
    }
    let points: Vec<Embedding> = (0..pixels)
        .map(|p| {
            if map.alpha[p] > 0.5 {
                unit(std::array::from_fn(|k| map.features[k * pixels + p]))
            } else {
                [0.0; INSTANCE_DIM]
            }
        })
        .collect();
    let weights: Vec<f32> = map.alpha.iter().map(|&a| if a > 0.5 { a } else { 0.0 }).collect();
    cluster_points(&points, &weights, params)
}

/// Clusters every view independently (views in parallel).
pub fn cluster_views(
    maps: &[FeatureMap<'_>],
    params: &ClusterParams,
) -> Result<Vec<Clustering>, ClusterError> {
    maps.par_iter().map(|m| cluster_view(m, params)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn a_two_region_view_splits_into_two_ids_and_transparent_pixels_get_none() {
        // 40×40: left half code e0, right half code e1 (noise ±0.15 per entry), top row
        // transparent.
        let (w, h) = (40, 40);
        let pixels = w * h;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut features: Vec<f32> =
            (0..INSTANCE_DIM * pixels).map(|_| rng.random_range(-0.15..0.15)).collect();
        let mut alpha = vec![1.0; pixels];
        for p in 0..pixels {
            let k = usize::from(p % w >= w / 2);
            features[k * pixels + p] += 1.0;
        }
        alpha[..w].fill(0.2);
        let c = cluster_view(
            &FeatureMap { features: &features, alpha: &alpha },
            &ClusterParams::default(),
        )
        .unwrap();
        assert_eq!(c.prototypes.len(), 2);
        assert!(c.ids[..w].iter().all(|&id| id == 0));
        let (left, right) = (c.ids[w], c.ids[w + w - 1]);
        assert!(left != 0 && right != 0 && left != right);
        for p in w..pixels {
            assert_eq!(c.ids[p], if p % w < w / 2 { left } else { right }, "pixel {p}");
        }
        let bad = FeatureMap { features: &features[1..], alpha: &alpha };
        assert!(matches!(
            cluster_views(&[bad], &ClusterParams::default()),
            Err(ClusterError::Shape { .. })
        ));
    }
}
