//! The network under ONNX Runtime, the one [`Backend`] today: finds the shared library
//! (`ORT_DYLIB_PATH` or the setup step's `.deps/`), loads a model, checks its inputs, outputs
//! and metadata against `proto::signature` (an error names the file and the tensor), reads the
//! shape classifier the file may carry, notes whether the network has the optional `rays`
//! input (then required on every run), sets intra-op threads from the core count, warms up,
//! and runs batches of views into planar output arrays.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use inssplat_proto::shape::ShapeClassifier;
use inssplat_proto::signature::{self, TensorSpec};
use ort::session::Session;

use super::{Backend, ModelOutput, Network, RayInput, RuntimeError};
use ort::value::{TensorElementType, TensorRef, ValueType};

/// A loaded, signature-checked ONNX model.
pub struct Model {
    session: Session,
    pub path: PathBuf,
    pub network: Network,
}

/// The folders a workspace file with no path given is looked for in, nearest first: the working
/// directory and every folder above it, then the binary's folder and every folder above it.
pub(crate) fn search_folders() -> Vec<PathBuf> {
    let roots = [
        std::env::current_dir().ok(),
        std::env::current_exe().ok().and_then(|e| e.parent().map(Path::to_path_buf)),
    ];
    roots
        .into_iter()
        .flatten()
        .flat_map(|r| r.ancestors().map(Path::to_path_buf).collect::<Vec<_>>())
        .collect()
}

/// Default place of the library unpacked by scripts/setup, relative to the workspace.
fn default_library() -> Option<PathBuf> {
    for dir in search_folders() {
        let Ok(entries) = std::fs::read_dir(dir.join(".deps")) else { continue };
        let mut found: Vec<PathBuf> = entries
            .flatten()
            .map(|e| e.path())
            .filter(|p| {
                p.file_name().is_some_and(|n| n.to_string_lossy().starts_with("onnxruntime-"))
            })
            .flat_map(|d| std::fs::read_dir(d).into_iter().flatten().flatten().map(|e| e.path()))
            .filter(|p| {
                p.file_name().is_some_and(|n| n.to_string_lossy().starts_with("libonnxruntime.so."))
            })
            .collect();
        found.sort();
        if let Some(p) = found.pop() {
            return Some(p);
        }
    }
    None
}

/// Loads the ONNX Runtime library once per process.
fn init_runtime() -> Result<&'static ort::environment::Environment, RuntimeError> {
    static ENV: OnceLock<Result<ort::environment::Environment, String>> = OnceLock::new();
    let path = match std::env::var_os("ORT_DYLIB_PATH").map(PathBuf::from).filter(|p| p.is_file()) {
        Some(p) => p,
        None => default_library().ok_or_else(|| RuntimeError::LibraryMissing {
            default: ".deps/onnxruntime-*/libonnxruntime.so.*".into(),
        })?,
    };
    let env = ENV.get_or_init(|| {
        ort::init_from(&path)
            .map_err(|e| e.to_string())
            .and_then(|b| b.with_name("inssplat").build().map_err(|e| e.to_string()))
    });
    env.as_ref().map_err(|message| RuntimeError::Library { path, message: message.clone() })
}

/// A session on the ONNX file `path` with `threads` intra-op threads (an error names the file).
pub(crate) fn session(path: &Path, threads: usize) -> Result<Session, RuntimeError> {
    if !path.is_file() {
        return Err(RuntimeError::ModelMissing { path: path.to_path_buf() });
    }
    let env = init_runtime()?;
    let load_err =
        |e: ort::Error| RuntimeError::Load { path: path.to_path_buf(), message: e.to_string() };
    Session::builder(env)
        .map_err(load_err)?
        .with_intra_threads(threads.max(1))
        .map_err(|e| load_err(e.into()))?
        // Within a run the threads spin between operators rather than sleep and wake for each;
        // when the run ends they stop, leaving the cores to the stages (rayon) that follow.
        // Against no spinning at all: the request at 8 views of 512² 0.92× (register 0.88×, the
        // detector 0.94×, the network 0.94×; `inssplat-eval bench`, medians of 3 paired runs).
        .with_intra_op_spinning(true)
        .map_err(|e| load_err(e.into()))?
        .with_config_entry("session.force_spinning_stop", "1")
        .map_err(|e| load_err(e.into()))?
        .commit_from_file(path)
        .map_err(load_err)
}

impl Model {
    /// Loads `path`, checks it against the signature, and runs one warm-up batch.
    pub fn load(path: &Path, threads: usize) -> Result<Self, RuntimeError> {
        let load_err =
            |e: ort::Error| RuntimeError::Load { path: path.to_path_buf(), message: e.to_string() };
        let session = session(path, threads)?;
        check_tensors(
            path,
            "input",
            &signature::INPUTS,
            session.inputs().iter().map(|o| (o.name(), o.dtype())),
        )?;
        check_tensors(
            path,
            "output",
            &signature::OUTPUTS,
            session.outputs().iter().map(|o| (o.name(), o.dtype())),
        )?;
        let rays_input = session
            .inputs()
            .iter()
            .find(|o| o.name() == signature::INPUT_RAYS.name)
            .map(|o| (o.name(), o.dtype()));
        let rays_shape = match rays_input {
            Some(input) => {
                check_tensors(path, "input", &[signature::INPUT_RAYS], std::iter::once(input))?;
                input.1.tensor_shape().map(|s| s.to_vec())
            }
            None => None,
        };
        let meta = session.metadata().map_err(load_err)?;
        let get = |key: &'static str| {
            meta.custom(key).ok_or_else(|| RuntimeError::Metadata {
                path: path.to_path_buf(),
                key,
                problem: "missing".into(),
            })
        };
        let io = get(signature::META_IO_VERSION)?;
        if io != signature::IO_VERSION {
            let problem = format!("`{io}`, this build speaks `{}`", signature::IO_VERSION);
            return Err(RuntimeError::Metadata {
                path: path.to_path_buf(),
                key: signature::META_IO_VERSION,
                problem,
            });
        }
        let number = |key: &'static str| -> Result<usize, RuntimeError> {
            let v = get(key)?;
            v.parse().map_err(|_| RuntimeError::Metadata {
                path: path.to_path_buf(),
                key,
                problem: format!("`{v}` is not a number"),
            })
        };
        let resolution = {
            let key = signature::META_RESOLUTION;
            let v = get(key)?;
            match v.split_once('x').map(|(h, w)| (h.parse::<usize>(), w.parse::<usize>())) {
                Some((Ok(h), Ok(w))) if h == w && h > 0 => h,
                _ => {
                    let problem =
                        format!("`{v}`: expected a square \"<H>x<W>\" size such as \"128x128\"");
                    return Err(RuntimeError::Metadata { path: path.to_path_buf(), key, problem });
                }
            }
        };
        let sem_dim = number(signature::META_SEM_DIM)?;
        let optional = |key: &'static str| {
            meta.custom(key).map(|_| number(key)).transpose().and_then(|n| match n {
                Some(0) => Err(RuntimeError::Metadata {
                    path: path.to_path_buf(),
                    key,
                    problem: "`0` is not a size".into(),
                }),
                n => Ok(n),
            })
        };
        let size_multiple = optional(signature::META_SIZE_MULTIPLE)?;
        let patch = optional(signature::META_PATCH)?;
        let model_version = get(signature::META_MODEL_VERSION)?;
        let shapes = meta
            .custom(signature::META_SHAPE_CLASSIFIER)
            .map(|json| ShapeClassifier::from_json(&json))
            .transpose()
            .map_err(|e| RuntimeError::Metadata {
                path: path.to_path_buf(),
                key: signature::META_SHAPE_CLASSIFIER,
                problem: e.to_string(),
            })?;
        drop(meta);
        let rays = rays_shape
            .map(|shape| RayInput::of_shape(path, &shape, resolution, patch))
            .transpose()?;
        let network = Network { resolution, size_multiple, sem_dim, model_version, shapes, rays };
        let mut model = Self { session, path: path.to_path_buf(), network };
        let size = [resolution, resolution];
        let warm = vec![0.5f32; 2 * 3 * resolution * resolution];
        let warm_rays = rays.map(|r| vec![0.0f32; r.values(2, size)]);
        model.run(&warm, 2, size, warm_rays.as_deref())?;
        Ok(model)
    }
}

impl Backend for Model {
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
        let [h, w] = size;
        if !self.network.takes(size) {
            return Err(RuntimeError::Run(format!(
                "this network takes no {h}×{w} input (trained at {r}², sides multiples of {m:?})",
                r = self.network.resolution,
                m = self.network.size_multiple
            )));
        }
        assert_eq!(images.len(), views * 3 * h * w, "image batch size");
        let run_err = |e: ort::Error| RuntimeError::Run(e.to_string());
        let mut inputs = vec![(
            signature::INPUT_IMAGES.name,
            TensorRef::from_array_view(([views, 3, h, w], images)).map_err(run_err)?,
        )];
        match (self.network.rays, rays) {
            (None, None) => {}
            (Some(input), Some(rays)) if rays.len() == input.values(views, size) => {
                let channels = inssplat_proto::rays::ray_channels(input.k);
                let shape = [views, input.tokens(size), channels];
                inputs.push((
                    signature::INPUT_RAYS.name,
                    TensorRef::from_array_view((shape, rays)).map_err(run_err)?,
                ));
            }
            (Some(input), given) => {
                let given = given.map_or("none".to_string(), |g| format!("{} values", g.len()));
                return Err(RuntimeError::Run(format!(
                    "this network reads its cameras as rays ({} values for {views} views), given {given}",
                    input.values(views, size)
                )));
            }
            (None, Some(_)) => {
                return Err(RuntimeError::Run(
                    "this network reads no camera rays, and some were given".into(),
                ));
            }
        }
        let outputs = self.session.run(inputs).map_err(run_err)?;
        let take = |spec: &TensorSpec| -> Result<Vec<f32>, RuntimeError> {
            let (_, data) = outputs[spec.name]
                .try_extract_tensor::<f32>()
                .map_err(|e| RuntimeError::Run(e.to_string()))?;
            Ok(data.to_vec())
        };
        Ok(ModelOutput {
            views,
            height: h,
            width: w,
            sem_dim: self.network.sem_dim,
            camera: take(&signature::OUTPUT_CAMERA)?,
            depth: take(&signature::OUTPUT_DEPTH)?,
            depth_conf: take(&signature::OUTPUT_DEPTH_CONF)?,
            gaussians: take(&signature::OUTPUT_GAUSSIANS)?,
            instance: take(&signature::OUTPUT_INSTANCE)?,
            semantic: take(&signature::OUTPUT_SEMANTIC)?,
            sem_proj_weight: take(&signature::OUTPUT_SEM_PROJ_WEIGHT)?,
            sem_proj_bias: take(&signature::OUTPUT_SEM_PROJ_BIAS)?,
        })
    }
}

/// Checks that every tensor of `expected` is present with the right element type and rank.
fn check_tensors<'a>(
    path: &Path,
    side: &str,
    expected: &[TensorSpec],
    actual: impl Iterator<Item = (&'a str, &'a ValueType)>,
) -> Result<(), RuntimeError> {
    let actual: Vec<_> = actual.collect();
    for spec in expected {
        let err = |problem: String| RuntimeError::Signature {
            path: path.to_path_buf(),
            tensor: spec.name.into(),
            problem,
        };
        let Some((_, ty)) = actual.iter().find(|(n, _)| *n == spec.name) else {
            let names: Vec<_> = actual.iter().map(|(n, _)| *n).collect();
            return Err(err(format!("missing {side} (the model has {names:?})")));
        };
        match (ty.tensor_type(), ty.tensor_shape()) {
            (Some(TensorElementType::Float32), Some(shape)) if shape.len() == spec.rank => {}
            (Some(TensorElementType::Float32), Some(shape)) => {
                return Err(err(format!(
                    "rank {}, expected {} {}",
                    shape.len(),
                    spec.rank,
                    spec.shape
                )));
            }
            (Some(t), _) => return Err(err(format!("element type {t:?}, expected float32"))),
            (None, _) => return Err(err("not a tensor".into())),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::RayInput;

    /// A `rays` input is read as its patch side and rays a patch (from a square grid tiling the
    /// resolution, or from the file's patch side where the count is symbolic); a shape that is
    /// neither, or no 6·K² channels, is named.
    #[test]
    fn a_rays_input_is_read_from_its_shape_or_named() {
        let path = Path::new("m.onnx");
        let input = RayInput::of_shape(path, &[-1, 256, 24], 128, None)
            .expect("16×16 patches of 8 pixels, 2×2 rays");
        assert_eq!((input.patch, input.k, input.values(3, [128, 128])), (8, 2, 3 * 256 * 24));
        let wide = RayInput::of_shape(path, &[-1, -1, 24], 128, Some(8)).expect("patch side 8");
        assert_eq!((wide.tokens([96, 128]), wide.values(2, [96, 128])), (192, 2 * 192 * 24));
        for (bad, patch) in [
            (&[-1, 255, 24][..], None),
            (&[-1, 256, 25], None),
            (&[-1, 256], None),
            (&[-1, 49, 6], None),
            (&[-1, -1, 24], None),
            (&[-1, -1, 24], Some(7)),
        ] {
            let err = RayInput::of_shape(path, bad, 128, patch).expect_err("refused").to_string();
            assert!(err.contains("m.onnx") && err.contains("`rays`"), "{err}");
        }
    }
}
