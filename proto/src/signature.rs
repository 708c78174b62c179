//! The model's I/O signature: the one hand-off between the trainer (which exports the ONNX
//! graph) and the server (which runs it). Names, element types, ranks and meanings of every
//! tensor, the metadata keys, and the version string both sides must agree on.
//!
//! `N` is the number of views (a dynamic axis, 2–16), `H`×`W` the input's size (the trained
//! [`META_RESOLUTION`], or any multiple of [`META_SIZE_MULTIPLE`] in a file that has it), `d_s`
//! the semantic feature width (metadata [`META_SEM_DIM`]). The world frame is view 0's
//! camera frame (OpenCV axes), so view 0's pose is the identity.

/// Version of this signature; stored in the model's metadata under [`META_IO_VERSION`].
pub const IO_VERSION: &str = "inssplat-io/1";

/// Views per request the model accepts.
pub const MIN_VIEWS: usize = 2;
pub const MAX_VIEWS: usize = 16;

/// Width of the text embedding space (all-MiniLM-L6-v2).
pub const TEXT_DIM: usize = 384;

/// Channels of the per-pixel Gaussian head, in order: offset xyz (3), log-scale (3),
/// rotation w,x,y,z (4), opacity logit (1), SH DC colour (3).
pub const GAUSSIAN_CHANNELS: usize = 14;

/// Layout of a `camera` row: translation (3), rotation w,x,y,z (4), fov_y, fov_x (radians).
pub const CAMERA_CHANNELS: usize = 9;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ElementType {
    F32,
}

/// One tensor of the signature.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TensorSpec {
    pub name: &'static str,
    pub element: ElementType,
    /// Shape with symbolic dimensions, for messages and docs.
    pub shape: &'static str,
    pub rank: usize,
    pub meaning: &'static str,
}

const fn f32_tensor(
    name: &'static str,
    shape: &'static str,
    rank: usize,
    meaning: &'static str,
) -> TensorSpec {
    TensorSpec { name, element: ElementType::F32, shape, rank, meaning }
}

pub const INPUT_IMAGES: TensorSpec = f32_tensor(
    "images",
    "[N, 3, H, W]",
    4,
    "RGB in [0, 1], each photo fitted into H×W (the long side at the model resolution, bars where its aspect differs)",
);

/// Optional: read only by networks trained with the cameras as input (the trainer's
/// `--camera-rays K`); the service gives it the known cameras ([`crate::rays::patch_rays`]).
pub const INPUT_RAYS: TensorSpec = f32_tensor(
    "rays",
    "[N, T, 6·K²]",
    3,
    "each patch's K×K Plücker rays (direction, moment) in view 0's frame, centres over the scene's median depth",
);

pub const OUTPUT_CAMERA: TensorSpec = f32_tensor(
    "camera",
    "[N, 9]",
    2,
    "world→camera pose (OpenCV axes, world = view 0's camera): translation xyz, rotation w,x,y,z (unnormalized), fov_y, fov_x in radians",
);
pub const OUTPUT_DEPTH: TensorSpec =
    f32_tensor("depth", "[N, 1, H, W]", 4, "depth along the camera z axis, metres (positive)");
pub const OUTPUT_DEPTH_CONF: TensorSpec =
    f32_tensor("depth_conf", "[N, 1, H, W]", 4, "depth confidence, > 0 (larger is surer)");
pub const OUTPUT_GAUSSIANS: TensorSpec = f32_tensor(
    "gaussians",
    "[N, 14, H, W]",
    4,
    "per-pixel Gaussian: offset xyz (camera frame, metres), log-scale xyz, rotation w,x,y,z (camera frame, unnormalized), opacity logit, SH DC rgb",
);
pub const OUTPUT_INSTANCE: TensorSpec = f32_tensor(
    "instance",
    "[N, 8, H, W]",
    4,
    "instance embedding S (compared after L2 normalization)",
);
pub const OUTPUT_SEMANTIC: TensorSpec =
    f32_tensor("semantic", "[N, d_s, H, W]", 4, "compact semantic feature L");
pub const OUTPUT_SEM_PROJ_WEIGHT: TensorSpec =
    f32_tensor("sem_proj_weight", "[384, d_s]", 2, "Φ_sem weight: text-space feature = W·L + b");
pub const OUTPUT_SEM_PROJ_BIAS: TensorSpec = f32_tensor("sem_proj_bias", "[384]", 1, "Φ_sem bias");

pub const INPUTS: [TensorSpec; 1] = [INPUT_IMAGES];
pub const OUTPUTS: [TensorSpec; 8] = [
    OUTPUT_CAMERA,
    OUTPUT_DEPTH,
    OUTPUT_DEPTH_CONF,
    OUTPUT_GAUSSIANS,
    OUTPUT_INSTANCE,
    OUTPUT_SEMANTIC,
    OUTPUT_SEM_PROJ_WEIGHT,
    OUTPUT_SEM_PROJ_BIAS,
];

/// ONNX metadata keys (custom_metadata_map).
pub const META_IO_VERSION: &str = "inssplat.io_version";
pub const META_MODEL_VERSION: &str = "inssplat.model_version";
/// The size trained at, as `"<H>x<W>"` in pixels, e.g. `"128x128"` (square).
pub const META_RESOLUTION: &str = "inssplat.resolution";
/// Optional: a number of pixels; the file takes any input whose height and width are
/// multiples of it (its patch grid then of the photo's aspect). Without it the input is
/// [`META_RESOLUTION`] only.
pub const META_SIZE_MULTIPLE: &str = "inssplat.size_multiple";
/// Optional: the patch side in pixels, which a file whose `rays` input has a symbolic patch
/// count needs (its rays tile the input's patches).
pub const META_PATCH: &str = "inssplat.patch";
pub const META_SEM_DIM: &str = "inssplat.sem_dim";
pub const META_TRAIN_STEPS: &str = "inssplat.train_steps";
/// Optional: the shape classifier ([`crate::shape::ShapeClassifier`]) as JSON.
pub const META_SHAPE_CLASSIFIER: &str = "inssplat.shape_classifier";

/// Looks up a tensor of the signature by name.
pub fn spec(name: &str) -> Option<&'static TensorSpec> {
    INPUTS.iter().chain(OUTPUTS.iter()).find(|t| t.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_ranks_match_shapes() {
        let all: Vec<_> = INPUTS.iter().chain(OUTPUTS.iter()).collect();
        for (i, t) in all.iter().enumerate() {
            assert!(all[i + 1..].iter().all(|u| u.name != t.name), "duplicate {}", t.name);
            assert_eq!(t.shape.split(',').count(), t.rank, "{}", t.name);
        }
        assert_eq!(spec("gaussians").unwrap().rank, 4);
        assert!(spec("nope").is_none());
    }
}
