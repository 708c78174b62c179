//! Stage "model": the network's one forward pass over the letterboxed views. A network that
//! reads its cameras as rays gets the known cameras' rays, else none (zero) before
//! registration; known depth, where given, replaces the depth head's (an oracle of the
//! evaluation).

use inssplat_proto::Camera;
use inssplat_proto::rays::patch_rays;

use super::decode::ModelImage;
use crate::backend::{Backend, ModelOutput};
use crate::reconstruct::PipelineError;

/// What the caller knows of the views beforehand (nothing, for a user's photos).
#[derive(Debug, Clone, Default)]
pub struct Known {
    /// Known cameras of the inputs, in order (world→camera in any metric frame, intrinsics at
    /// the model resolution), used instead of the network's camera head; the network's depth,
    /// Gaussians and features are placed with them.
    pub poses: Option<Vec<Camera>>,
    /// Known depth of the inputs, `[V][H][W]` metres at the model resolution (0: no surface,
    /// that pixel keeps the depth head's value), used instead of the depth head wherever the
    /// depth is read (registration, back-projection); the network's per-pixel offsets,
    /// Gaussians and features are kept.
    pub depth: Option<Vec<f32>>,
    /// The median depth of the input views in the units of [`Known::poses`], which a network
    /// that reads its cameras as rays needs with them (it divides the camera centres).
    pub median_depth: Option<f32>,
}

/// The network's outputs and the input batch they came from (planar `[V][3][H][W]`).
pub struct NetworkPass {
    pub out: ModelOutput,
    pub batch: Vec<f32>,
}

/// Runs the network on the decoded views.
pub fn run(
    backend: &mut dyn Backend,
    decoded: &[ModelImage],
    known: &Known,
) -> Result<NetworkPass, PipelineError> {
    let views = decoded.len();
    let batch: Vec<f32> = decoded.iter().flat_map(|d| d.planar.iter().copied()).collect();
    let [w, h] = decoded.first().map_or([0, 0], |d| d.letterbox.input);
    let size = [h as usize, w as usize];
    let rays = match (backend.network().rays, &known.poses, known.median_depth) {
        (None, _, _) => None,
        (Some(input), None, _) => Some(vec![0.0; input.values(views, size)]),
        (Some(input), Some(poses), Some(scale)) if scale > 0.0 => {
            Some(patch_rays(poses, size, input.patch, input.k, scale))
        }
        (Some(_), Some(_), _) => return Err(PipelineError::RaysNeedScale),
    };
    let mut out = backend.run(&batch, views, size, rays.as_deref())?;
    if let Some(depth) = &known.depth {
        if depth.len() != out.depth.len() {
            let pixels = out.height * out.width;
            return Err(PipelineError::Depth { given: depth.len(), views: out.views, pixels });
        }
        for (d, &k) in out.depth.iter_mut().zip(depth) {
            if k > 0.0 {
                *d = k;
            }
        }
    }
    Ok(NetworkPass { out, batch })
}
