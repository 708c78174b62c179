use super::*;
use inssplat_proto::gaussian::{Gaussian, logit};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `per` noisy copies of each one-hot code e_0..e_{k-1} (noise uniform in ±0.15 per entry),
/// with the true code index.
fn blobs(k: usize, per: usize, seed: u64) -> (Vec<Embedding>, Vec<usize>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut points = Vec::new();
    let mut truth = Vec::new();
    for c in 0..k {
        for _ in 0..per {
            let mut v: Embedding = std::array::from_fn(|_| rng.random_range(-0.15..0.15));
            v[c] += 1.0;
            points.push(unit(v));
            truth.push(c);
        }
    }
    (points, truth)
}

/// Ids agree with the truth up to a renaming (and every point has an id).
fn assert_bijection(ids: &[u32], truth: &[usize], k: usize) {
    let mut id_of = vec![None; k];
    for (&id, &t) in ids.iter().zip(truth) {
        assert_ne!(id, 0);
        assert_eq!(*id_of[t].get_or_insert(id), id, "code {t} split");
    }
    let mut seen: Vec<u32> = id_of.into_iter().flatten().collect();
    seen.sort_unstable();
    seen.dedup();
    assert_eq!(seen.len(), k, "two codes merged");
}

#[test]
fn recovers_well_separated_codes_and_orders_ids_by_size() {
    let (mut points, mut truth) = blobs(5, 300, 1);
    // Code 3 gets 300 more points: it must become id 1.
    let (extra, _) = blobs(5, 300, 2);
    points.extend_from_slice(&extra[900..1200]);
    truth.extend(std::iter::repeat_n(3, 300));
    let weights = vec![1.0; points.len()];
    let c = cluster_points(&points, &weights, &ClusterParams::default()).unwrap();
    assert_eq!(c.prototypes.len(), 5);
    // The default sample bound, 1500 of the 1800 points; every point still gets its id.
    assert_eq!(c.sampled, 1500);
    assert_bijection(&c.ids, &truth, 5);
    assert_eq!(c.ids[900], 1);
    assert!(c.prototypes[0][3] > 0.95, "{:?}", c.prototypes[0]);
}

#[test]
fn subsample_is_bounded_and_follows_the_weights() {
    let (points, truth) = blobs(2, 5000, 3);
    // Code 1 weighs 9× code 0: about 90% of the sample comes from it.
    let weights: Vec<f32> = truth.iter().map(|&t| if t == 1 { 9.0 } else { 1.0 }).collect();
    let sample = weighted_sample(&points, &weights, 1000, 7);
    assert_eq!(sample.len(), 1000);
    assert!(sample.windows(2).all(|w| w[0] < w[1]));
    let heavy = sample.iter().filter(|&&i| truth[i] == 1).count();
    assert!((860..=940).contains(&heavy), "{heavy}");
    // Zero weights and zero vectors are never drawn.
    let mut w0 = weights.clone();
    w0[..5000].fill(0.0);
    assert!(weighted_sample(&points, &w0, 1000, 7).iter().all(|&i| i >= 5000));
    let params = ClusterParams { max_samples: 1000, ..ClusterParams::default() };
    let c = cluster_points(&points, &weights, &params).unwrap();
    assert_eq!(c.sampled, 1000);
    assert_bijection(&c.ids, &truth, 2);
}

#[test]
fn noise_takes_the_nearest_prototype_only_within_the_threshold() {
    let (mut points, truth) = blobs(3, 200, 4);
    let near = unit([0.8, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.6]); // cos 0.8 to e0
    let far = unit([0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]); // cos 0.29 to e0
    let mut broken = [0.0; INSTANCE_DIM];
    broken[0] = f32::NAN;
    points.extend([near, far, [0.0; INSTANCE_DIM], unit(broken)]);
    let mut weights = vec![1.0; points.len()];
    weights[600] = 0.0; // not sampled: only assignment decides
    let c = cluster_points(&points, &weights, &ClusterParams::default()).unwrap();
    assert_bijection(&c.ids[..600], &truth, 3);
    assert_eq!(c.ids[600], c.ids[0]);
    assert_eq!((c.ids[601], c.ids[602], c.ids[603]), (0, 0, 0));
}

#[test]
fn clustering_a_scene_writes_instance_ids() {
    let (points, truth) = blobs(3, 150, 5);
    let mut scene = GaussianScene::with_sem_dim(0);
    for p in &points {
        scene.push(Gaussian {
            mean: [0.0; 3],
            log_scale: [0.0; 3],
            rotation: [1.0, 0.0, 0.0, 0.0],
            logit_opacity: logit(0.9),
            sh_dc: [0.0; 3],
            confidence: 2.0,
            instance_embedding: p.map(|x| 3.0 * x), // magnitude must not matter
            semantic: &[],
            instance_id: 0,
        });
    }
    let c = cluster_instances(&mut scene, &ClusterParams::default()).unwrap();
    assert_eq!(scene.instance_id, c.ids);
    assert_bijection(&scene.instance_id, &truth, 3);
}

#[test]
fn two_objects_with_one_embedding_part_by_position_only_with_a_position_weight() {
    // Codes 0 and 1, 200 points each; code 0's points lie in two clusters 4 m apart (two
    // chairs the network embeds alike), code 1's between them.
    let (points, codes) = blobs(2, 400, 8);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut jitter = || rng.random_range(-0.3..0.3);
    let (mut positions, mut truth) = (Vec::new(), Vec::new());
    for (i, &code) in codes.iter().enumerate() {
        let (x, object) = match (code, i % 2) {
            (0, 0) => (-2.0, 0),
            (0, _) => (2.0, 1),
            _ => (0.0, 2),
        };
        positions.push([x + jitter(), jitter(), jitter()]);
        truth.push(object);
    }
    let positions = normalized_positions(&positions);
    let weights = vec![1.0; points.len()];
    let alone = ClusterParams { position_weight: 0.0, ..ClusterParams::default() };
    let c = cluster_points_at(&points, Some(&positions), &weights, &alone).unwrap();
    assert_eq!(c.prototypes.len(), 2, "the embeddings alone see two instances");
    assert_eq!(
        c,
        cluster_points(&points, &weights, &alone).unwrap(),
        "weight 0 ignores the positions"
    );
    let c =
        cluster_points_at(&points, Some(&positions), &weights, &ClusterParams::default()).unwrap();
    assert_bijection(&c.ids, &truth, 3);
    // Both chairs keep code 0's embedding as their prototype.
    let chairs: Vec<&Embedding> = c.prototypes.iter().filter(|p| p[0] > 0.9).collect();
    assert_eq!(chairs.len(), 2, "{:?}", c.prototypes);
}

#[test]
fn too_few_points_give_no_instances_and_bad_params_are_named() {
    let (points, _) = blobs(1, 5, 6);
    let c = cluster_points(&points, &[1.0; 5], &ClusterParams::default()).unwrap();
    assert!(c.prototypes.is_empty() && c.ids == vec![0; 5]);
    let bad = ClusterParams { min_cosine: 2.0, ..ClusterParams::default() };
    let err = cluster_points(&points, &[1.0; 5], &bad).unwrap_err();
    assert!(err.to_string().contains("min_cosine"), "{err}");
    let bad = ClusterParams { position_weight: -1.0, ..ClusterParams::default() };
    let err = cluster_points(&points, &[1.0; 5], &bad).unwrap_err();
    assert!(err.to_string().contains("position_weight"), "{err}");
}
