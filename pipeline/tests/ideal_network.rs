//! The request path behind a network double, no model file: a [`Backend`] that answers with
//! the ideal outputs of the analytic room ([`inssplat_geometry::analytic_room`]: the true
//! cameras and depth, each object's own instance embedding, and its label's semantic code,
//! which Φ_sem maps onto the label's MiniLM text) instead of running a network. Every stage
//! after the network runs as the service runs it; it must find the room's boxes with the
//! true outlines in every view and name each by its label.

use glam::Quat;
use inssplat_geometry::analytic_room::{
    SEM_DIM, VOCABULARY, ideal_outputs, render_scene, ring_cameras,
};
use inssplat_geometry::ideal::label_projection;
use inssplat_metrics::instance_scores;
use inssplat_pipeline::backend::{Backend, ModelOutput, Network, RuntimeError};
use inssplat_pipeline::output::png_bytes;
use inssplat_pipeline::reconstruct::{InputImage, PipelineConfig, reconstruct};
use inssplat_proto::Camera;
use inssplat_proto::dataset::Scene;
use inssplat_text::{LabelCache, TextEmbedder};

const VIEWS: usize = 6;
const SIZE: u32 = 96;

/// A network that knows the answer: the same outputs whatever it is shown.
struct IdealNetwork {
    network: Network,
    out: ModelOutput,
}

impl Backend for IdealNetwork {
    fn network(&self) -> &Network {
        &self.network
    }

    fn run(
        &mut self,
        images: &[f32],
        views: usize,
        size: [usize; 2],
        rays: Option<&[f32]>,
    ) -> Result<ModelOutput, RuntimeError> {
        assert!(rays.is_none(), "this network reads no rays");
        assert_eq!(size, [SIZE as usize; 2]);
        assert_eq!((views, images.len()), (VIEWS, VIEWS * 3 * (SIZE * SIZE) as usize));
        Ok(self.out.clone())
    }
}

/// The camera head's output for `cameras`, in the network's frame (world = view 0's camera):
/// translation, rotation (w, x, y, z), vertical and horizontal field of view.
fn camera_channels(cameras: &[Camera]) -> Vec<f32> {
    let (r0, t0) = (cameras[0].rotation, cameras[0].translation);
    cameras
        .iter()
        .flat_map(|c| {
            let rotation: Quat = c.rotation * r0.inverse();
            let translation = c.translation - rotation * t0;
            let k = &c.intrinsics;
            let fov = |size: u32, f: f32| 2.0 * (0.5 * size as f32 / f).atan();
            [
                translation.x,
                translation.y,
                translation.z,
                rotation.w,
                rotation.x,
                rotation.y,
                rotation.z,
                fov(k.height, k.fy),
                fov(k.width, k.fx),
            ]
        })
        .collect()
}

fn ideal_network(scene: &Scene, cameras: &[Camera], labels: &LabelCache) -> IdealNetwork {
    let planes = ideal_outputs(scene, 0.0, 3);
    let texts = labels.embed(&VOCABULARY).expect("the vocabulary's embeddings");
    let (sem_proj_weight, sem_proj_bias) = label_projection(&texts);
    let all = |f: fn(&inssplat_geometry::ideal::ViewPlanes) -> &Vec<f32>| {
        planes.iter().flat_map(|p| f(p).iter().copied()).collect::<Vec<f32>>()
    };
    let out = ModelOutput {
        views: VIEWS,
        height: SIZE as usize,
        width: SIZE as usize,
        sem_dim: SEM_DIM,
        camera: camera_channels(cameras),
        depth: all(|p| &p.depth),
        depth_conf: all(|p| &p.conf),
        gaussians: all(|p| &p.gaussians),
        instance: all(|p| &p.instance),
        semantic: all(|p| &p.semantic),
        sem_proj_weight,
        sem_proj_bias,
    };
    let network = Network {
        resolution: SIZE as usize,
        size_multiple: None,
        sem_dim: SEM_DIM,
        model_version: "ideal".into(),
        shapes: None,
        rays: None,
    };
    IdealNetwork { network, out }
}

#[test]
fn an_ideal_network_behind_the_backend_gives_the_rooms_objects_named() {
    let cameras = ring_cameras(VIEWS, SIZE);
    let scene = render_scene(&cameras);
    let labels =
        LabelCache::new(TextEmbedder::from_env().expect("the text model (source .deps/env)"));
    let mut network = ideal_network(&scene, &cameras, &labels);
    let images: Vec<InputImage> = scene
        .frames
        .iter()
        .enumerate()
        .map(|(v, f)| {
            let rgb = image::RgbImage::from_raw(f.width(), f.height(), f.rgb.clone()).unwrap();
            InputImage { name: format!("{v}.png"), bytes: png_bytes(&rgb) }
        })
        .collect();
    let vocabulary: Vec<String> = VOCABULARY.iter().map(|l| l.to_string()).collect();
    // The camera head is exact: no registration (and so no heading search) to move it.
    let config = PipelineConfig { register: None, ..PipelineConfig::default() };
    let rec = reconstruct(&mut network, &labels, &images, &vocabulary, &config).unwrap();

    let stages: Vec<&str> = rec.timings.iter().map(|t| t.stage.as_str()).collect();
    let expected =
        "decode model superpixels backproject voxelize cluster vote masks label upsample";
    assert_eq!(stages.join(" "), expected, "the stages run, in order");
    for (v, (view, frame)) in rec.views.iter().zip(&scene.frames).enumerate() {
        let truth: Vec<u32> =
            frame.instances.as_ref().unwrap().iter().map(|&id| u32::from(id)).collect();
        let scores = instance_scores(&view.instance_ids, &truth).unwrap().expect("boxes in view");
        assert!(scores.miou > 0.85, "view {v}: instance mIoU {:.3}", scores.miou);
    }
    let mut named: Vec<&str> = rec.instances.iter().map(|i| i.label.as_str()).collect();
    named.sort();
    named.dedup();
    for label in ["cabinet", "chair", "table"] {
        assert!(named.contains(&label), "no {label} among {named:?}");
    }
    assert!(!named.iter().any(|l| ["lamp", "sofa", "bed", "plant"].contains(l)), "{named:?}");
}
