use super::*;
use inssplat_proto::gaussian::{Gaussian, logit};

/// Φ_sem from 2-d features to a 3-d text space: W = [[1, 0], [0, 1], [0, 0]], b = (0, 0, 0.5).
const W: [f32; 6] = [1.0, 0.0, 0.0, 1.0, 0.0, 0.0];
const B: [f32; 3] = [0.0, 0.0, 0.5];

fn proj() -> SemanticProjection<'static> {
    SemanticProjection { weight: &W, bias: &B }
}

/// A Gaussian of instance `id` with semantic feature `l`; nothing else matters here.
fn gaussian(id: u32, l: &[f32]) -> Gaussian<'_> {
    Gaussian {
        mean: [0.0; 3],
        log_scale: [0.0; 3],
        rotation: [1.0, 0.0, 0.0, 0.0],
        logit_opacity: logit(0.9),
        sh_dc: [0.0; 3],
        confidence: 1.0,
        instance_embedding: [0.0; 8],
        semantic: l,
        instance_id: id,
    }
}

fn scene(members: &[(u32, [f32; 2])]) -> GaussianScene {
    let mut s = GaussianScene::with_sem_dim(2);
    for (id, l) in members {
        s.push(gaussian(*id, l));
    }
    s
}

fn unit3(v: [f32; 3]) -> Vec<f32> {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.iter().map(|x| x / n).collect()
}

fn close(a: &[f32], b: &[f32]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5)
}

#[test]
fn prototypes_are_normalized_means_of_normalized_projections() {
    // Instance 1: projections (3, 0, 0.5) and (0, 1, 0.5) (normalized before the mean; the
    // first one's length must not dominate). Instance 3: one Gaussian. Id 0 is ignored and
    // id 2 has no Gaussian.
    let s = scene(&[(1, [3.0, 0.0]), (1, [0.0, 1.0]), (0, [5.0, 5.0]), (3, [0.0, -2.0])]);
    let p = semantic_prototypes(&s, &proj()).unwrap();
    assert_eq!(p.iter().map(|p| (p.id, p.gaussians)).collect::<Vec<_>>(), vec![(1, 2), (3, 1)]);
    let (a, b) = (unit3([3.0, 0.0, 0.5]), unit3([0.0, 1.0, 0.5]));
    let mean: Vec<f32> = a.iter().zip(&b).map(|(x, y)| x + y).collect();
    let n = mean.iter().map(|x| x * x).sum::<f32>().sqrt();
    assert!(
        close(&p[0].embedding, &mean.iter().map(|x| x / n).collect::<Vec<_>>()),
        "{:?}",
        p[0].embedding
    );
    assert!(close(&p[1].embedding, &unit3([0.0, -2.0, 0.5])));
    let bad = SemanticProjection { weight: &W[..4], bias: &B };
    assert!(matches!(
        semantic_prototypes(&s, &bad),
        Err(LabelError::Projection { expected: 6, .. })
    ));
}

#[test]
fn prototypes_match_the_definition_for_a_dense_projection() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let (text_dim, sem_dim) = (12, 5);
    let weight: Vec<f32> = (0..text_dim * sem_dim).map(|_| rng.random_range(-1.0..1.0)).collect();
    let bias: Vec<f32> = (0..text_dim).map(|_| rng.random_range(-0.5..0.5)).collect();
    let proj = SemanticProjection { weight: &weight, bias: &bias };
    let mut s = GaussianScene::with_sem_dim(sem_dim);
    for _ in 0..300 {
        let l: Vec<f32> = (0..sem_dim).map(|_| rng.random_range(-2.0..2.0)).collect();
        s.push(gaussian(rng.random_range(0..4), &l));
    }
    // The definition: mean of the normalized projections, normalized.
    let mut want = vec![vec![0.0f64; text_dim]; 3];
    for i in 0..s.len() {
        let id = s.instance_id[i] as usize;
        if id == 0 {
            continue;
        }
        let t: Vec<f64> = (0..text_dim)
            .map(|r| {
                let row = &weight[r * sem_dim..(r + 1) * sem_dim];
                bias[r] as f64
                    + row
                        .iter()
                        .zip(s.semantic_of(i))
                        .map(|(&w, &x)| w as f64 * x as f64)
                        .sum::<f64>()
            })
            .collect();
        let n = t.iter().map(|x| x * x).sum::<f64>().sqrt();
        want[id - 1].iter_mut().zip(&t).for_each(|(a, x)| *a += x / n);
    }
    let got = semantic_prototypes(&s, &proj).unwrap();
    assert_eq!(got.len(), 3);
    for (p, w) in got.iter().zip(&want) {
        let n = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        let w: Vec<f32> = w.iter().map(|x| (x / n) as f32).collect();
        assert!(close(&p.embedding, &w), "id {}: {:?} vs {w:?}", p.id, p.embedding);
    }
}

#[test]
fn labels_go_to_the_most_similar_vocabulary_entry() {
    let s = scene(&[(1, [1.0, 0.0]), (2, [0.0, 1.0]), (3, [0.0, 0.0])]);
    let p = semantic_prototypes(&s, &proj()).unwrap();
    // Vocabulary (unnormalized): 0 ≈ +y, 1 ≈ +x, 2 = −x. Instance 3 projects to (0, 0, 0.5):
    // cosine 0.51 with entry 0, 0.45 with entry 1.
    let vocab = vec![vec![0.0, 2.0, 1.2], vec![5.0, 0.0, 2.5], vec![-1.0, 0.0, 0.0]];
    let labels = assign_labels(&p, &vocab).unwrap();
    assert_eq!(labels.iter().map(|l| l.unwrap().label).collect::<Vec<_>>(), vec![1, 0, 0]);
    // Instance 1's projection (1, 0, 0.5) is parallel to entry 1: score 1.
    assert!((labels[0].unwrap().score - 1.0).abs() < 1e-5);
    let err = assign_labels(&p, &[vec![1.0; 4]]).unwrap_err();
    assert_eq!(err, LabelError::TextDim { index: 0, actual: 4, expected: 3 });
}

#[test]
fn query_returns_instances_within_the_margin_of_the_best() {
    let prototype = |id, v: [f32; 3]| InstancePrototype { id, embedding: unit3(v), gaussians: 1 };
    // Against the query +x: ids 1 and 4 score ≈ 1 and 0.995, id 2 scores 0.8, id 3 scores 0.
    let protos = [
        prototype(1, [1.0, 0.0, 0.0]),
        prototype(2, [0.8, 0.6, 0.0]),
        prototype(3, [0.0, 1.0, 0.0]),
        prototype(4, [1.0, 0.1, 0.0]),
    ];
    let hits = query(&protos, &[2.0, 0.0, 0.0], &[], &QueryRule::default()).unwrap();
    assert_eq!(hits.iter().map(|h| h.id).collect::<Vec<_>>(), vec![1, 4]);
    let wide = QueryRule { margin: 0.25, ..QueryRule::default() };
    assert_eq!(query(&protos, &[1.0, 0.0, 0.0], &[], &wide).unwrap().len(), 3);
    // Nothing is close enough: no hit, even for the best.
    assert!(query(&protos, &[0.0, 0.0, 1.0], &[], &QueryRule::default()).unwrap().is_empty());
    // Instance 4's own label scores 0.995 + 0.2: the query is far below it, so it is not named.
    let own = [1.0, 0.8, 0.0, 1.2];
    let hits = query(&protos, &[2.0, 0.0, 0.0], &own, &QueryRule::default()).unwrap();
    assert_eq!(hits.iter().map(|h| h.id).collect::<Vec<_>>(), vec![1]);
}
