//! Test and bench support: an owned set of Gaussians whose `splats()` borrows it as the
//! rasterizer's input. Each test file adds the builders it needs in its own `impl Scene`.

use inssplat_raster::render::Splats;

#[derive(Clone, Default)]
pub struct Scene {
    pub means: Vec<[f32; 3]>,
    pub log_scales: Vec<[f32; 3]>,
    pub rotations: Vec<[f32; 4]>,
    pub logits: Vec<f32>,
    pub features: Vec<f32>,
    pub channels: usize,
}

impl Scene {
    pub fn splats(&self) -> Splats<'_> {
        Splats {
            means: &self.means,
            log_scales: &self.log_scales,
            rotations: &self.rotations,
            logit_opacity: &self.logits,
            features: &self.features,
            channels: self.channels,
        }
    }
}
