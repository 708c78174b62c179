//! One job scene on a model worker: a dataset scene with an evaluation split is reconstructed
//! from its largest context set and scored by the `inssplat-eval score` protocol (the metrics go
//! into the job's result); any other scene (a photo folder, a dataset scene without a split)
//! is reconstructed from its photos as `inssplat reconstruct` would. Either way the
//! reconstruction is written to the scene store under the task's scene id.

use std::path::Path;

use anyhow::Context;
use inssplat_proto::api::StageTiming;
use inssplat_proto::dataset::Scene;
use inssplat_proto::signature::{MAX_VIEWS, MIN_VIEWS};
use inssplat_text::LabelCache;

use super::SceneTask;
use inssplat_eval::ClusterMode;
use inssplat_eval::scene::{Settings, evaluate_scene_keeping};
use inssplat_pipeline::backend::Model;
use inssplat_pipeline::output::write_reconstruction;
use inssplat_pipeline::reconstruct::{PipelineConfig, reconstruct};
use inssplat_pipeline::{inputs, vocab};

/// Runs `task` (with the job's refinement steps where it set them, else `config`'s), writing
/// its reconstruction to `out`; returns the stage timings and the evaluation metrics when the
/// scene carried ground truth.
pub fn run_scene(
    model: &mut Model,
    labels: &LabelCache,
    config: &PipelineConfig,
    task: &SceneTask,
    out: &Path,
) -> anyhow::Result<(Vec<StageTiming>, Option<serde_json::Value>)> {
    let config = &config.with_refine_steps(task.refine_steps);
    let split = task
        .input
        .join("transforms.json")
        .is_file()
        .then(|| Scene::load(&task.input))
        .transpose()?;
    let (rec, photos, metrics) = match split.filter(|s| s.eval.is_some()) {
        Some(scene) => {
            let views = (MIN_VIEWS..=MAX_VIEWS)
                .rev()
                .find(|&v| scene.eval.as_ref().is_some_and(|e| e.context_for(v).is_some()))
                .context("the eval split has no context set of 2-16 views")?;
            let mut vocabulary = scene.label_vocabulary();
            vocabulary.extend(task.vocabulary.iter().flatten().cloned());
            vocabulary.sort();
            vocabulary.dedup();
            let settings = Settings {
                vocabulary: &vocabulary,
                pipeline: config,
                cluster: ClusterMode::ThreeD,
                perturbation: None,
                switches: Default::default(),
                query_rules: &[],
                photos: None,
            };
            let (scores, rec, photos) =
                evaluate_scene_keeping(model, labels, &scene, views, &settings)?;
            (rec, photos, Some(serde_json::to_value(&scores)?))
        }
        None => {
            let paths = inputs::photo_paths(std::slice::from_ref(&task.input))?;
            let photos = inputs::read_photos(&paths)?;
            let vocabulary = match &task.vocabulary {
                Some(v) => v.clone(),
                None => vocab::vocabulary(None)?,
            };
            let rec = reconstruct(model, labels, &photos, &vocabulary, config)?;
            (rec, photos, None)
        }
    };
    write_reconstruction(&rec, &photos, out)?;
    Ok((rec.timings, metrics))
}
