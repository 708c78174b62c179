//! Fitting the shape classifier ([`inssplat_proto::shape::ShapeClassifier`]): descriptors of
//! the labelled objects of synthesized rooms, measured on points back-projected from true
//! depth with the true cameras of a random subset of 2–16 views (what a request sees), by the
//! same `inssplat_understand::label::shape` code the server runs on its Gaussians; an MLP fitted
//! to them with cross-entropy, the lengths rescaled at random each epoch (the network's depth
//! has a scale error of its own), optionally with the cosines of each instance's semantic
//! prototype to the labels' texts as well (a semantic classifier, fitted on the pipeline's own
//! instances); and [`attach`], which stores the result in a model file.

use std::collections::BTreeMap;
use std::path::Path;

use burn::module::Module;
use burn::nn::loss::CrossEntropyLossConfig;
use burn::nn::{Linear, LinearConfig};
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use burn::tensor::activation::relu;
use glam::Vec3;
use inssplat_proto::dataset::Scene;
use inssplat_proto::shape::{
    DESCRIPTOR, Dense, LENGTHS, LabelledDescriptor, ShapeClassifier, label_cosines,
};
use inssplat_proto::signature::{META_MODEL_VERSION, META_SHAPE_CLASSIFIER};
use inssplat_text::LabelCache;
use inssplat_understand::label::shape::{camera_up, descriptor, ground};
use prost::Message;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::export::onnx_pb::{ModelProto, StringStringEntryProto};

/// View counts a request may have, drawn uniformly for each scene.
const VIEW_COUNTS: [usize; 4] = [2, 4, 8, 16];

/// The views of `scene` whose points describe its objects: a random count of
/// [`VIEW_COUNTS`] (at most the scene's frames), in a random subset, for scene `seed`.
pub fn draw_views(frames: usize, seed: u64) -> Vec<usize> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let k = VIEW_COUNTS[rng.random_range(0..VIEW_COUNTS.len())].min(frames);
    let mut all: Vec<usize> = (0..frames).collect();
    all.shuffle(&mut rng);
    all.truncate(k);
    all
}

/// Descriptors of the labelled instances that `views` of `scene` see, from true depth and
/// cameras, with the floor found as the server finds it. Frames without depth or instance
/// masks add nothing.
pub fn scene_examples(scene: &Scene, views: &[usize]) -> Vec<LabelledDescriptor> {
    let mut points = Vec::new();
    let mut members: BTreeMap<u16, (Vec<Vec3>, Vec<[f32; 3]>)> = BTreeMap::new();
    for &v in views {
        let f = &scene.frames[v];
        let (Some(depth), Some(ids)) = (&f.depth, &f.instances) else { continue };
        let w = f.width() as usize;
        for (p, (&z, &id)) in depth.iter().zip(ids).enumerate() {
            if z <= 0.0 {
                continue;
            }
            let x = f.camera.camera_to_world(f.camera.unproject(
                (p % w) as f32 + 0.5,
                (p / w) as f32 + 0.5,
                z,
            ));
            points.push(x);
            if id > 0 {
                let m = members.entry(id).or_default();
                m.0.push(x);
                m.1.push(std::array::from_fn(|c| f32::from(f.rgb[3 * p + c]) / 255.0));
            }
        }
    }
    let cameras: Vec<_> = views.iter().map(|&v| scene.frames[v].camera).collect();
    let g = ground(&points, camera_up(&cameras));
    members
        .iter()
        .filter_map(|(id, (p, c))| {
            let label = scene.instances.iter().find(|i| i.id == u32::from(*id))?.label.clone();
            Some(LabelledDescriptor {
                label,
                descriptor: descriptor(p, c, &g)?,
                prototype: Vec::new(),
                scene: String::new(),
            })
        })
        .collect()
}

/// Knobs of [`fit`].
#[derive(Debug, Clone)]
pub struct FitShapesConfig {
    pub hidden: usize,
    pub epochs: usize,
    pub lr: f64,
    /// Lengths are multiplied by a factor drawn log-uniformly from [1/j, j] each epoch.
    pub scale_jitter: f32,
    pub seed: u64,
    /// Post-hoc logit adjustment (Menon et al., 2021): `τ·ln p(label)` (the label's share
    /// of the training examples) is taken off each output's bias, so that the most probable
    /// label trades accuracy on frequent labels for recall on rare ones (what mIoU and mAcc,
    /// means over classes, reward). 0 leaves the fit as it is.
    pub logit_adjust: f32,
}

impl Default for FitShapesConfig {
    fn default() -> Self {
        Self { hidden: 64, epochs: 1500, lr: 3e-3, scale_jitter: 1.25, seed: 7, logit_adjust: 0.0 }
    }
}

#[derive(Module, Debug)]
struct Mlp {
    layers: Vec<Linear>,
}

impl Mlp {
    fn forward(&self, mut x: Tensor<2>) -> Tensor<2> {
        for (i, l) in self.layers.iter().enumerate() {
            x = l.forward(x);
            if i + 1 < self.layers.len() {
                x = relu(x);
            }
        }
        x
    }
}

/// What a fit reached.
#[derive(Debug, Clone, PartialEq)]
pub struct FitShapesReport {
    pub train_accuracy: f64,
    /// On the held-out examples (none: `None`).
    pub held_out_accuracy: Option<f64>,
    pub final_loss: f32,
}

/// The label texts a semantic classifier compares prototypes with, in `labels` order.
fn label_texts(labels: &[String], cache: &LabelCache) -> Result<Vec<Vec<f32>>, String> {
    let names: Vec<&str> = labels.iter().map(String::as_str).collect();
    let texts = cache.embed(&names).map_err(|e| format!("embedding the labels: {e}"))?;
    Ok(texts.iter().map(|t| t.to_vec()).collect())
}

/// The classifier's input for `e` (before standardizing): its descriptor, then with `texts`
/// the cosines of its prototype to them. Err names the example that has no prototype.
fn example_input(
    e: &LabelledDescriptor,
    i: usize,
    texts: Option<&[Vec<f32>]>,
) -> Result<Vec<f32>, String> {
    let mut x = e.descriptor.to_vec();
    if let Some(texts) = texts {
        if e.prototype.is_empty() {
            return Err(format!(
                "example {i} ({}) has no prototype: a semantic classifier fits on `inssplat-eval score --shape-examples` files",
                e.label
            ));
        }
        x.extend(label_cosines(&e.prototype, texts));
    }
    Ok(x)
}

/// Fits the classifier to `train` (labels: every label in it, sorted); scores it on
/// `held_out` (examples whose label `train` lacks count as wrong). With `semantic` (the
/// label texts' source) it is a [`ShapeClassifier::semantic`] one, and every example needs
/// its prototype. `on_epoch(epoch, loss)` reports progress.
pub fn fit(
    train: &[LabelledDescriptor],
    held_out: &[LabelledDescriptor],
    config: &FitShapesConfig,
    semantic: Option<&LabelCache>,
    on_epoch: &dyn Fn(usize, f32),
) -> Result<(ShapeClassifier, FitShapesReport), String> {
    if train.is_empty() {
        return Err("no training examples".into());
    }
    let mut labels: Vec<String> = train.iter().map(|e| e.label.clone()).collect();
    labels.sort();
    labels.dedup();
    let texts = semantic.map(|cache| label_texts(&labels, cache)).transpose()?;
    let inputs: Vec<Vec<f32>> = train
        .iter()
        .enumerate()
        .map(|(i, e)| example_input(e, i, texts.as_deref()))
        .collect::<Result<_, _>>()?;
    let d = inputs[0].len();
    let n = train.len() as f32;
    let mean: Vec<f32> = (0..d).map(|a| inputs.iter().map(|x| x[a]).sum::<f32>() / n).collect();
    let std: Vec<f32> = (0..d)
        .map(|a| {
            (inputs.iter().map(|x| (x[a] - mean[a]).powi(2)).sum::<f32>() / n).sqrt().max(1e-4)
        })
        .collect();
    let targets: Vec<i64> =
        train.iter().map(|e| labels.binary_search(&e.label).expect("from train") as i64).collect();

    let device = Device::flex().autodiff();
    device.seed(config.seed);
    let widths = [d, config.hidden, config.hidden, labels.len()];
    let mut mlp = Mlp {
        layers: widths.windows(2).map(|w| LinearConfig::new(w[0], w[1]).init(&device)).collect(),
    };
    let mut optim = AdamConfig::new().init();
    let ce = CrossEntropyLossConfig::new().init(&device);
    let y = Tensor::<1, Int>::from_data(TensorData::new(targets.clone(), [train.len()]), &device);
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let log_j = config.scale_jitter.max(1.0).ln();
    let mut final_loss = f32::NAN;
    for epoch in 0..config.epochs {
        let mut x = Vec::with_capacity(train.len() * d);
        for input in &inputs {
            let s = if log_j > 0.0 { rng.random_range(-log_j..log_j).exp() } else { 1.0 };
            x.extend(
                (0..d).map(|a| (input[a] * if a < LENGTHS { s } else { 1.0 } - mean[a]) / std[a]),
            );
        }
        let x = Tensor::<2>::from_data(TensorData::new(x, [train.len(), d]), &device);
        let loss = ce.forward(mlp.forward(x), y.clone());
        final_loss = loss.clone().into_scalar::<f32>();
        if !final_loss.is_finite() {
            return Err(format!("epoch {epoch}: the loss is not finite"));
        }
        on_epoch(epoch, final_loss);
        let grads = GradientsParams::from_grads(loss.backward(), &mlp);
        mlp = optim.step(config.lr, mlp, grads);
    }
    let mut layers = mlp
        .layers
        .iter()
        .map(|l| {
            let w = l
                .weight
                .val()
                .into_data()
                .try_into_vec_as::<f32>()
                .map_err(|e| format!("{e:?}"))?;
            let [inputs, outputs] = l.weight.dims();
            // burn stores [inputs][outputs]; the contract is [outputs][inputs].
            let weight = (0..outputs)
                .flat_map(|o| (0..inputs).map(move |i| (o, i)))
                .map(|(o, i)| w[i * outputs + o])
                .collect();
            let bias = match &l.bias {
                Some(b) => {
                    b.val().into_data().try_into_vec_as::<f32>().map_err(|e| format!("{e:?}"))?
                }
                None => vec![0.0; outputs],
            };
            Ok(Dense { inputs, outputs, weight, bias })
        })
        .collect::<Result<Vec<_>, String>>()?;
    adjust_logits(layers.last_mut().expect("three layers"), &targets, config.logit_adjust);
    let semantic = texts.is_some();
    let classifier =
        ShapeClassifier { labels, mean, std, layers, provenance: String::new(), semantic };
    classifier.validate().map_err(|e| e.to_string())?;
    let texts = texts.unwrap_or_default();
    let report = FitShapesReport {
        train_accuracy: accuracy(&classifier, train, &texts)?.unwrap_or(0.0),
        held_out_accuracy: accuracy(&classifier, held_out, &texts)?,
        final_loss,
    };
    Ok((classifier, report))
}

/// Takes `tau`·ln of each label's share of `targets` off `last`'s bias (labels every
/// target has, so no share is 0).
fn adjust_logits(last: &mut Dense, targets: &[i64], tau: f32) {
    if tau == 0.0 {
        return;
    }
    let mut counts = vec![0usize; last.outputs];
    targets.iter().for_each(|&t| counts[t as usize] += 1);
    let n = targets.len() as f32;
    for (b, &c) in last.bias.iter_mut().zip(&counts) {
        *b -= tau * (c as f32 / n).ln();
    }
}

/// Share of `examples` whose most probable label is theirs (`None` without examples);
/// `texts` are the embeddings of a semantic classifier's labels (else unused). Err names an
/// example a semantic classifier cannot read.
pub fn accuracy(
    c: &ShapeClassifier,
    examples: &[LabelledDescriptor],
    texts: &[Vec<f32>],
) -> Result<Option<f64>, String> {
    let mut right = 0;
    for (i, e) in examples.iter().enumerate() {
        let cosines = example_input(e, i, c.semantic.then_some(texts))?.split_off(DESCRIPTOR.len());
        let p = c.probabilities(&e.descriptor, &cosines);
        let best = (0..p.len()).max_by(|&a, &b| p[a].total_cmp(&p[b]));
        right += usize::from(best.is_some_and(|b| c.labels[b] == e.label));
    }
    Ok((!examples.is_empty()).then(|| right as f64 / examples.len() as f64))
}

#[derive(Debug, thiserror::Error)]
pub enum AttachError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: not an ONNX model ({message})")]
    NotOnnx { path: String, message: String },
}

/// Writes `model` to `out` with `classifier` under [`META_SHAPE_CLASSIFIER`] (replacing one
/// already there) and, when given, a new model version; the graph and weights are copied as
/// they are.
pub fn attach(
    model: &Path,
    out: &Path,
    classifier: &ShapeClassifier,
    version: Option<&str>,
) -> Result<(), AttachError> {
    fn io(path: &Path) -> impl Fn(std::io::Error) -> AttachError + '_ {
        move |source| AttachError::Io { path: path.display().to_string(), source }
    }
    let bytes = std::fs::read(model).map_err(io(model))?;
    let mut proto = ModelProto::decode(bytes.as_slice()).map_err(|e| AttachError::NotOnnx {
        path: model.display().to_string(),
        message: e.to_string(),
    })?;
    if proto.graph.is_none() {
        return Err(AttachError::NotOnnx {
            path: model.display().to_string(),
            message: "no graph".into(),
        });
    }
    let mut set = |key: &str, value: String| {
        proto.metadata_props.retain(|p| p.key.as_deref() != Some(key));
        proto
            .metadata_props
            .push(StringStringEntryProto { key: Some(key.into()), value: Some(value) });
    };
    set(META_SHAPE_CLASSIFIER, classifier.to_json());
    if let Some(v) = version {
        set(META_MODEL_VERSION, v.to_string());
    }
    std::fs::write(out, proto.encode_to_vec()).map_err(io(out))
}
