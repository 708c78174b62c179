//! `GaussianScene`: a set of 3D Gaussians as a structure of arrays, in the storage convention
//! of 3DGS (log scales, logit opacity, normalized w,x,y,z quaternions, colour as SH degree-0
//! coefficients) plus inssplat's per-Gaussian extras: confidence, an 8-d instance embedding,
//! a d_s-d semantic feature and an instance id (0 = no instance).

use serde::{Deserialize, Serialize};

/// Width of the instance embedding S.
pub const INSTANCE_DIM: usize = 8;

/// SH degree-0 basis constant: colour = 0.5 + SH_C0 · f_dc.
pub const SH_C0: f32 = 0.282_094_8;

/// Converts an RGB colour in [0, 1] to its SH DC coefficient.
pub fn rgb_to_sh_dc(c: f32) -> f32 {
    (c - 0.5) / SH_C0
}

/// Converts an SH DC coefficient to an RGB colour (unclamped).
pub fn sh_dc_to_rgb(f: f32) -> f32 {
    0.5 + SH_C0 * f
}

/// L2-normalized copy; a zero or non-finite vector becomes zero (it joins no instance).
pub fn unit<const N: usize>(v: [f32; N]) -> [f32; N] {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n.is_finite() && n > 1e-12 { v.map(|x| x / n) } else { [0.0; N] }
}

pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

pub fn logit(p: f32) -> f32 {
    let p = p.clamp(1e-6, 1.0 - 1e-6);
    (p / (1.0 - p)).ln()
}

/// Metadata that travels with a scene (PLY `comment` lines).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SceneMeta {
    /// Program that wrote the scene.
    pub producer: String,
    /// Model version string that produced the Gaussians, if any.
    pub model_version: Option<String>,
    /// World up axis as a signed axis name ("+y", "-y", "+z", ...), if known.
    pub up_axis: Option<String>,
    /// Instance id → text label.
    pub labels: Vec<(u32, String)>,
}

/// 3D Gaussians, structure of arrays. Every per-Gaussian vector has [`len`](Self::len)
/// entries; `semantic` has `len · sem_dim`, row-major per Gaussian.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct GaussianScene {
    pub means: Vec<[f32; 3]>,
    pub log_scales: Vec<[f32; 3]>,
    /// Unit quaternions w, x, y, z.
    pub rotations: Vec<[f32; 4]>,
    pub logit_opacity: Vec<f32>,
    pub sh_dc: Vec<[f32; 3]>,
    pub confidence: Vec<f32>,
    pub instance_embedding: Vec<[f32; INSTANCE_DIM]>,
    pub sem_dim: usize,
    pub semantic: Vec<f32>,
    /// 0 = no instance.
    pub instance_id: Vec<u32>,
    pub meta: SceneMeta,
}

/// A field whose length disagrees with `means`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("GaussianScene field `{field}` has {actual} entries, expected {expected}")]
pub struct LengthMismatch {
    pub field: &'static str,
    pub expected: usize,
    pub actual: usize,
}

impl GaussianScene {
    /// An empty scene whose semantic features have `sem_dim` channels.
    pub fn with_sem_dim(sem_dim: usize) -> Self {
        Self { sem_dim, ..Default::default() }
    }

    pub fn len(&self) -> usize {
        self.means.len()
    }

    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    /// Checks that every field has one entry per Gaussian.
    pub fn validate(&self) -> Result<(), LengthMismatch> {
        let n = self.len();
        let checks = [
            ("log_scales", self.log_scales.len(), n),
            ("rotations", self.rotations.len(), n),
            ("logit_opacity", self.logit_opacity.len(), n),
            ("sh_dc", self.sh_dc.len(), n),
            ("confidence", self.confidence.len(), n),
            ("instance_embedding", self.instance_embedding.len(), n),
            ("semantic", self.semantic.len(), n * self.sem_dim),
            ("instance_id", self.instance_id.len(), n),
        ];
        for (field, actual, expected) in checks {
            if actual != expected {
                return Err(LengthMismatch { field, expected, actual });
            }
        }
        Ok(())
    }

    /// Semantic feature of Gaussian `i`.
    pub fn semantic_of(&self, i: usize) -> &[f32] {
        &self.semantic[i * self.sem_dim..(i + 1) * self.sem_dim]
    }

    /// Makes room for `n` more Gaussians in every field.
    pub fn reserve(&mut self, n: usize) {
        self.means.reserve(n);
        self.log_scales.reserve(n);
        self.rotations.reserve(n);
        self.logit_opacity.reserve(n);
        self.sh_dc.reserve(n);
        self.confidence.reserve(n);
        self.instance_embedding.reserve(n);
        self.semantic.reserve(n * self.sem_dim);
        self.instance_id.reserve(n);
    }

    /// Moves every Gaussian of `other` (same `sem_dim`) to the end of this scene.
    pub fn append(&mut self, other: GaussianScene) {
        assert_eq!(other.sem_dim, self.sem_dim, "semantic feature width");
        self.means.extend(other.means);
        self.log_scales.extend(other.log_scales);
        self.rotations.extend(other.rotations);
        self.logit_opacity.extend(other.logit_opacity);
        self.sh_dc.extend(other.sh_dc);
        self.confidence.extend(other.confidence);
        self.instance_embedding.extend(other.instance_embedding);
        self.semantic.extend(other.semantic);
        self.instance_id.extend(other.instance_id);
    }

    /// Appends one Gaussian. `semantic` must have `sem_dim` entries.
    pub fn push(&mut self, g: Gaussian<'_>) {
        assert_eq!(g.semantic.len(), self.sem_dim, "semantic feature width");
        self.means.push(g.mean);
        self.log_scales.push(g.log_scale);
        self.rotations.push(g.rotation);
        self.logit_opacity.push(g.logit_opacity);
        self.sh_dc.push(g.sh_dc);
        self.confidence.push(g.confidence);
        self.instance_embedding.push(g.instance_embedding);
        self.semantic.extend_from_slice(g.semantic);
        self.instance_id.push(g.instance_id);
    }
}

/// One Gaussian, for [`GaussianScene::push`].
#[derive(Debug, Clone, Copy)]
pub struct Gaussian<'a> {
    pub mean: [f32; 3],
    pub log_scale: [f32; 3],
    pub rotation: [f32; 4],
    pub logit_opacity: f32,
    pub sh_dc: [f32; 3],
    pub confidence: f32,
    pub instance_embedding: [f32; INSTANCE_DIM],
    pub semantic: &'a [f32],
    pub instance_id: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_and_opacity_conversions_invert() {
        for c in [0.0, 0.25, 0.5, 1.0] {
            assert!((sh_dc_to_rgb(rgb_to_sh_dc(c)) - c).abs() < 1e-6);
        }
        for p in [0.01, 0.5, 0.9] {
            assert!((sigmoid(logit(p)) - p).abs() < 1e-6);
        }
    }

    #[test]
    fn validate_names_the_short_field() {
        let mut s = GaussianScene::with_sem_dim(2);
        s.push(Gaussian {
            mean: [0.0; 3],
            log_scale: [0.0; 3],
            rotation: [1.0, 0.0, 0.0, 0.0],
            logit_opacity: 0.0,
            sh_dc: [0.0; 3],
            confidence: 1.0,
            instance_embedding: [0.0; INSTANCE_DIM],
            semantic: &[1.0, 2.0],
            instance_id: 3,
        });
        assert!(s.validate().is_ok());
        assert_eq!(s.semantic_of(0), &[1.0, 2.0]);
        s.semantic.pop();
        assert_eq!(s.validate().unwrap_err().field, "semantic");
    }
}
