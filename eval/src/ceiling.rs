//! Instances on the context views, to tell the embeddings' limit from the clustering's: the
//! instance mIoU of the clustering's own ids on the input views, against that of the best
//! assignment the embeddings allow when the true instances are known (each pixel takes the
//! true instance whose prototype, the normalized mean of its members' embeddings, is nearest).
//! The second approximates the best that any clustering of these embeddings can do (the
//! "ceiling"): when it is low, the network is what limits instance mIoU; when the first lies far
//! below it, the clustering is.

use inssplat_metrics::MetricError;
use inssplat_metrics::segmentation::instance_scores;
use inssplat_proto::INSTANCE_DIM;
use inssplat_proto::gaussian::unit;

/// One context view at the model resolution, all maps `[H][W]`.
pub struct ContextView<'a> {
    /// 1 + the index of the Gaussian each pixel was merged into, 0 for none
    /// ([`inssplat_pipeline::reconstruct::ViewResult::gaussians`]).
    pub gaussians: &'a [u32],
    /// The clustering's instance ids.
    pub ids: &'a [u32],
    /// True instance ids, 0 = background.
    pub truth: &'a [u32],
}

/// Pooled instance mIoU over the context views: (of the clustering, of the nearest true
/// prototype), with `embeddings` the Gaussians' instance embeddings; `None` when no view has a
/// true instance.
pub fn context_instances(
    embeddings: &[[f32; INSTANCE_DIM]],
    views: &[ContextView<'_>],
) -> Result<Option<(f64, f64)>, MetricError> {
    let embedding = |g: u32| (g > 0).then(|| unit(embeddings[g as usize - 1]));
    let ids = views.iter().flat_map(|v| v.truth.iter().copied()).max().unwrap_or(0) as usize;
    let mut sums = vec![[0.0f32; INSTANCE_DIM]; ids + 1];
    for view in views {
        for (&g, &id) in view.gaussians.iter().zip(view.truth) {
            if let Some(e) = embedding(g) {
                sums[id as usize].iter_mut().zip(e).for_each(|(s, x)| *s += x);
            }
        }
    }
    let prototypes: Vec<(u32, [f32; INSTANCE_DIM])> = sums
        .into_iter()
        .enumerate()
        .filter(|(_, s)| s.iter().any(|&x| x != 0.0))
        .map(|(id, s)| (id as u32, unit(s)))
        .collect();
    let nearest = |e: [f32; INSTANCE_DIM]| {
        let cos = |p: &[f32; INSTANCE_DIM]| p.iter().zip(&e).map(|(a, b)| a * b).sum::<f32>();
        prototypes.iter().max_by(|a, b| cos(&a.1).total_cmp(&cos(&b.1))).map_or(0, |p| p.0)
    };
    let (mut clustered, mut ceiling) = (Vec::new(), Vec::new());
    for view in views {
        let best: Vec<u32> =
            view.gaussians.iter().map(|&g| embedding(g).map_or(0, nearest)).collect();
        if let Some(s) = instance_scores(view.ids, view.truth)? {
            clustered.extend(s.matches.iter().map(|m| m.iou));
        }
        if let Some(s) = instance_scores(&best, view.truth)? {
            ceiling.extend(s.matches.iter().map(|m| m.iou));
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    Ok((!clustered.is_empty()).then(|| (mean(&clustered), mean(&ceiling))))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn axis(i: usize) -> [f32; INSTANCE_DIM] {
        std::array::from_fn(|k| if k == i { 2.0 } else { 0.0 })
    }

    #[test]
    fn separable_embeddings_reach_the_ceiling_that_a_merging_clustering_misses() {
        // One view of 6 pixels: background, instance 1 (2 px), instance 2 (3 px); the last
        // pixel made no Gaussian. Gaussians: 0 background, 1 and 2 instance 1's and 2's.
        let embeddings = [axis(0), axis(1), axis(2)];
        let truth = [0, 1, 1, 2, 2, 2];
        let gaussians = [1, 2, 2, 3, 3, 0];
        let merged = [0, 1, 1, 1, 1, 0];
        let view = ContextView { gaussians: &gaussians, ids: &merged, truth: &truth };
        let (clustered, ceiling) = context_instances(&embeddings, &[view]).unwrap().unwrap();
        // The merged id covers pixels 1–4: instance 1 IoU 2/4, instance 2 IoU 2/5.
        assert!((clustered - 0.45).abs() < 1e-12, "{clustered}");
        // Nearest true prototype: instance 1 exact, instance 2 misses its Gaussian-less pixel.
        assert!((ceiling - (1.0 + 2.0 / 3.0) / 2.0).abs() < 1e-12, "{ceiling}");
    }

    #[test]
    fn embeddings_that_do_not_separate_cap_the_ceiling() {
        let embeddings = [axis(0)];
        let truth = [1, 1, 2, 2];
        let gaussians = [1, 1, 1, 1];
        let view = ContextView { gaussians: &gaussians, ids: &[1, 1, 2, 2], truth: &truth };
        let (clustered, ceiling) = context_instances(&embeddings, &[view]).unwrap().unwrap();
        assert_eq!(clustered, 1.0);
        // Every pixel goes to one prototype: one instance at IoU 1/2, the other at 0 or 1/2.
        assert!(ceiling <= 0.5, "{ceiling}");
    }

    #[test]
    fn no_true_instance_gives_none() {
        let view = ContextView { gaussians: &[1, 1], ids: &[1, 1], truth: &[0, 0] };
        assert_eq!(context_instances(&[axis(0)], &[view]).unwrap(), None);
    }
}
