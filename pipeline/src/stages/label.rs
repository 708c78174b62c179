//! Stage "label": each instance's semantic prototype (its Gaussians' semantic features through
//! Φ_sem), moved toward what the model's shape classifier makes of the instance's size,
//! height above the floor and colour, then toward the classes the object detector's boxes
//! vote for ([`inssplat_understand::label::detections`]), then named by the nearest text of
//! the vocabulary ([`inssplat_understand::label`]). A detector class pulls toward the words of
//! the vocabulary near it in the text space (`couch` toward `sofa`), and toward nothing when no
//! word is near enough (so a person or a car found in a photo is not forced onto a room's
//! word). The names go into the scene's metadata and the instance table, with the evidence
//! that gave each.

use inssplat_proto::api::{DetectorVote, InstanceOut, NamedBy};
use inssplat_proto::shape::{DESCRIPTOR, ShapeClassifier, label_cosines};
use inssplat_proto::{Camera, GaussianScene};
use inssplat_text::{Embedding, LabelCache, cosine};
use inssplat_understand::label::detections::{ViewDetections, class_votes, fuse_votes};
use inssplat_understand::label::shape::{fuse, instance_descriptors};
use inssplat_understand::label::{
    InstancePrototype, LabelMatch, SemanticProjection, assign_labels, semantic_prototypes,
};

use super::stage_err;
use crate::detector::Detector;
use crate::reconstruct::PipelineError;

/// The naming of a scene's instances.
pub struct Naming {
    /// Each instance's semantic prototype, after the shape classifier moved it.
    pub prototypes: Vec<InstancePrototype>,
    /// The prototypes as the features gave them (what a semantic classifier reads).
    pub unfused: Vec<InstancePrototype>,
    /// Each prototype's best label in the vocabulary, if any.
    pub matches: Vec<Option<LabelMatch>>,
    /// Each instance's shape descriptor (ids with too few Gaussians left out).
    pub descriptors: Vec<(u32, [f32; DESCRIPTOR.len()])>,
    /// Which evidence gave each prototype its label.
    pub named_by: Vec<NamedBy>,
    /// The detector's strongest vote for each prototype's instance, where it voted.
    pub detector_votes: Vec<Option<DetectorVote>>,
}

/// The object detector (its class names and how naming reads its boxes) and its boxes in the
/// input views.
pub struct DetectorEvidence<'a> {
    pub detector: &'a Detector,
    /// Each view's instance map with the boxes found in it.
    pub views: Vec<ViewDetections<'a>>,
}

/// What naming reads besides the scene.
pub struct LabelInputs<'a> {
    pub projection: SemanticProjection<'a>,
    pub cameras: &'a [Camera],
    /// The model's shape classifier, if it carries one.
    pub classifier: Option<&'a ShapeClassifier>,
    /// Weight of the classifier's text-space direction (0: the features alone).
    pub shape_weight: f32,
    pub labels: &'a LabelCache,
    pub vocabulary: &'a [String],
    /// The object detector's boxes, where it ran.
    pub detections: Option<DetectorEvidence<'a>>,
}

/// Names the instances of `scene`.
pub fn run(scene: &GaussianScene, inputs: &LabelInputs<'_>) -> Result<Naming, PipelineError> {
    let err = stage_err("label");
    let mut prototypes = semantic_prototypes(scene, &inputs.projection).map_err(|e| err(&e))?;
    let unfused = prototypes.clone();
    let (_, descriptors) = instance_descriptors(scene, inputs.cameras);
    if let Some(classifier) = inputs.classifier.filter(|_| inputs.shape_weight > 0.0) {
        let names: Vec<&str> = classifier.labels.iter().map(String::as_str).collect();
        let texts = inputs.labels.embed(&names).map_err(|e| err(&e))?;
        let probabilities: Vec<(u32, Vec<f32>)> = descriptors
            .iter()
            .filter_map(|(id, d)| {
                let cosines = match classifier.semantic {
                    true => {
                        label_cosines(&prototypes.iter().find(|p| p.id == *id)?.embedding, &texts)
                    }
                    false => Vec::new(),
                };
                Some((*id, classifier.probabilities(d, &cosines)))
            })
            .collect();
        fuse(&mut prototypes, &probabilities, &texts, inputs.shape_weight);
    }
    let words: Vec<&str> = inputs.vocabulary.iter().map(String::as_str).collect();
    let texts = inputs.labels.embed(&words).map_err(|e| err(&e))?;
    let by_features = assign_labels(&unfused, &texts).map_err(|e| err(&e))?;
    let by_shape = assign_labels(&prototypes, &texts).map_err(|e| err(&e))?;
    let mut detector_votes = vec![None; prototypes.len()];
    if let Some(evidence) = &inputs.detections {
        let (classes, params) = (&evidence.detector.classes, &evidence.detector.params);
        let votes = class_votes(&evidence.views, classes.len(), params.min_pixels);
        // Only the classes that voted are embedded (each new text costs the encoder a pass).
        let voted: Vec<usize> =
            (0..classes.len()).filter(|&c| votes.iter().any(|v| v.votes[c] > 0.0)).collect();
        let names: Vec<&str> = voted.iter().map(|&c| classes[c].as_str()).collect();
        let class_texts = inputs.labels.embed(&names).map_err(|e| err(&e))?;
        let mut usable: Vec<Option<Vec<f32>>> = vec![None; classes.len()];
        for (&c, t) in voted.iter().zip(&class_texts) {
            usable[c] = word_family(t, &texts, params.min_cosine);
        }
        fuse_votes(&mut prototypes, &votes, &usable, params.weight);
        for (p, slot) in prototypes.iter().zip(&mut detector_votes) {
            let Some(v) = votes.iter().find(|v| v.id == p.id) else { continue };
            *slot = v.best().map(|(class, vote)| DetectorVote {
                class: classes[class].clone(),
                vote,
                views: v.views,
            });
        }
    }
    let matches = assign_labels(&prototypes, &texts).map_err(|e| err(&e))?;
    let label = |m: &Option<LabelMatch>| m.map(|m| m.label);
    let named_by = (0..matches.len())
        .map(|i| {
            if label(&matches[i]) != label(&by_shape[i]) {
                NamedBy::Detector
            } else if label(&by_shape[i]) != label(&by_features[i]) {
                NamedBy::Shape
            } else {
                NamedBy::Features
            }
        })
        .collect();
    Ok(Naming { prototypes, unfused, matches, descriptors, named_by, detector_votes })
}

/// The sum of the words of `words` at least `min_cosine` near `text` (unit text embeddings):
/// the kind of thing a detector's class says, among which the other evidence chooses (`dining
/// table`: table and coffee table); `None` when no word is that near.
fn word_family(text: &Embedding, words: &[Embedding], min_cosine: f32) -> Option<Vec<f32>> {
    let near: Vec<&Embedding> = words.iter().filter(|w| cosine(text, w) >= min_cosine).collect();
    (!near.is_empty())
        .then(|| (0..text.len()).map(|k| near.iter().map(|w| w[k]).sum::<f32>()).collect())
}

impl Naming {
    /// Vocabulary index of each instance id's label at index id − 1 (`None`: unnamed).
    pub fn label_of_id(&self, scene: &GaussianScene) -> Vec<Option<usize>> {
        let k = scene.instance_id.iter().copied().max().unwrap_or(0) as usize;
        let mut label_of_id = vec![None; k];
        for (p, m) in self.prototypes.iter().zip(&self.matches) {
            label_of_id[p.id as usize - 1] = m.map(|m| m.label);
        }
        label_of_id
    }

    /// Writes the instances' names, the model version and the up axis into the scene's metadata.
    pub fn write_meta(
        &self,
        scene: &mut GaussianScene,
        vocabulary: &[String],
        model_version: &str,
    ) {
        scene.meta.labels = self
            .prototypes
            .iter()
            .zip(&self.matches)
            .filter_map(|(p, m)| m.map(|m| (p.id, vocabulary[m.label].clone())))
            .collect();
        scene.meta.model_version = Some(model_version.to_string());
        scene.meta.up_axis = Some("-y".into());
    }

    /// Id, label, score, Gaussian count and bounding box of every instance.
    pub fn instance_table(&self, scene: &GaussianScene, vocabulary: &[String]) -> Vec<InstanceOut> {
        self.prototypes
            .iter()
            .zip(&self.matches)
            .zip(self.named_by.iter().zip(&self.detector_votes))
            .map(|((p, m), (named_by, detector))| {
                let mut bbox = [[f32::INFINITY; 3], [f32::NEG_INFINITY; 3]];
                for (mean, _) in
                    scene.means.iter().zip(&scene.instance_id).filter(|(_, id)| **id == p.id)
                {
                    for a in 0..3 {
                        bbox[0][a] = bbox[0][a].min(mean[a]);
                        bbox[1][a] = bbox[1][a].max(mean[a]);
                    }
                }
                InstanceOut {
                    id: p.id,
                    label: m.map_or_else(|| "unknown".to_string(), |m| vocabulary[m.label].clone()),
                    score: m.map_or(0.0, |m| m.score),
                    gaussians: p.gaussians,
                    bbox,
                    named_by: *named_by,
                    detector: detector.clone(),
                }
            })
            .collect()
    }
}
