//! Reading and validating a scene folder. Everything docs/DATASET.md says a reader must reject is
//! rejected here with the file and the field: missing or unreadable images, mismatched sizes
//! in a frame's image/depth/instance triple, non-finite or singular transforms, unknown
//! instance ids, and paths that leave the scene folder.

use std::path::{Component, Path, PathBuf};

use image::DynamicImage;

use super::error::{DatasetError, Problem};
use super::transforms::{EvalSplit, FrameJson, TransformsJson};
use super::{DEFAULT_DEPTH_UNIT_M, Frame, Scene};
use crate::camera::{Camera, Intrinsics};

impl Scene {
    /// Reads and validates the scene in `dir` (its `transforms.json` and every frame's files).
    pub fn load(dir: impl AsRef<Path>) -> Result<Scene, DatasetError> {
        let dir = dir.as_ref();
        let json_path = dir.join("transforms.json");
        let t = TransformsJson::read(&json_path)?;
        let err = |field: String, problem| DatasetError::new(&json_path, field, problem);
        if t.frames.is_empty() {
            return Err(err("frames".into(), Problem::Invalid("no frames".into())));
        }
        let depth_unit_m = t.depth_unit_m.unwrap_or(DEFAULT_DEPTH_UNIT_M);
        if !(depth_unit_m.is_finite() && depth_unit_m > 0.0) {
            return Err(err(
                "depth_unit_m".into(),
                Problem::Invalid(format!("{depth_unit_m} is not a positive number")),
            ));
        }
        let known =
            known_instance_ids(&t).map_err(|(field, msg)| err(field, Problem::Invalid(msg)))?;
        if let Some(eval) = &t.eval {
            validate_eval(eval, t.frames.len())
                .map_err(|(field, msg)| err(field, Problem::Invalid(msg)))?;
        }
        let frames = t
            .frames
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let ctx =
                    FrameCtx { dir, json_path: &json_path, index: i, known: &known, depth_unit_m };
                ctx.load(&t, f)
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Scene {
            dir: dir.to_path_buf(),
            instances: t.instances,
            frames,
            eval: t.eval,
            depth_unit_m,
        })
    }
}

impl TransformsJson {
    /// Parses a scene's `transforms.json` at `path` alone: its cameras, instances and split,
    /// without reading or checking the frames' files.
    pub fn read(path: &Path) -> Result<TransformsJson, DatasetError> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            let problem = if e.kind() == std::io::ErrorKind::NotFound {
                Problem::Missing
            } else {
                Problem::Unreadable(e.to_string())
            };
            DatasetError::new(path, "(file)", problem)
        })?;
        let de = &mut serde_json::Deserializer::from_str(&text);
        serde_path_to_error::deserialize(de).map_err(|e| {
            let field = match e.path().to_string() {
                p if p == "." => "(document)".to_string(),
                p => p,
            };
            DatasetError::new(path, field, Problem::Json(e.into_inner().to_string()))
        })
    }
}

/// Listed instance ids as a lookup table over the u16 range.
fn known_instance_ids(t: &TransformsJson) -> Result<Vec<bool>, (String, String)> {
    let mut known = vec![false; 1 << 16];
    for (k, inst) in t.instances.iter().enumerate() {
        let field = format!("instances[{k}].id");
        match inst.id {
            0 => return Err((field, "0 means `no instance` and cannot be listed".into())),
            id if id > u32::from(u16::MAX) => {
                return Err((field, format!("{id} does not fit a 16-bit mask")));
            }
            id if known[id as usize] => return Err((field, format!("id {id} is listed twice"))),
            id => known[id as usize] = true,
        }
        if inst.label.trim().is_empty() {
            return Err((format!("instances[{k}].label"), "empty label".into()));
        }
    }
    Ok(known)
}

fn validate_eval(eval: &EvalSplit, n_frames: usize) -> Result<(), (String, String)> {
    let check = |field: String, idx: &[usize]| -> Result<(), (String, String)> {
        match idx.iter().position(|&i| i >= n_frames) {
            Some(j) => Err((
                format!("{field}[{j}]"),
                format!("frame {} does not exist ({n_frames} frames)", idx[j]),
            )),
            None => Ok(()),
        }
    };
    check("eval.target".into(), &eval.target)?;
    for (views, idx) in &eval.context {
        let field = format!("eval.context.{views}");
        let n: usize =
            views.parse().map_err(|_| (field.clone(), "key must be a view count".to_string()))?;
        if n != idx.len() {
            return Err((field, format!("{} frames listed for {n} views", idx.len())));
        }
        check(field.clone(), idx)?;
        if let Some(i) = idx.iter().find(|i| eval.target.contains(i)) {
            return Err((field, format!("frame {i} is both context and target")));
        }
    }
    Ok(())
}

impl TransformsJson {
    /// The cameras of every frame, without reading any image (e.g. a reconstruction's
    /// predicted cameras, or cameras to render from); `json_path` names the file in errors.
    pub fn cameras(&self, json_path: &Path) -> Result<Vec<Camera>, DatasetError> {
        self.frames
            .iter()
            .enumerate()
            .map(|(index, f)| {
                let k = frame_intrinsics(self, f, json_path, index)?;
                Camera::from_nerfstudio(k, &f.transform_matrix).map_err(|e| {
                    DatasetError::new(
                        json_path,
                        format!("frames[{index}].transform_matrix"),
                        Problem::Transform(e),
                    )
                })
            })
            .collect()
    }
}

/// What loading one frame needs to know about its scene.
struct FrameCtx<'a> {
    dir: &'a Path,
    json_path: &'a Path,
    index: usize,
    known: &'a [bool],
    depth_unit_m: f64,
}

/// Whether `img` is smaller than `w`×`h` with the same shape: one side scaled, the other
/// scaled alike and rounded.
fn shrunk(img: &DynamicImage, (w, h): (u32, u32)) -> bool {
    let (iw, ih) = (img.width(), img.height());
    // Side `ia` of the image is side `a` of the frame scaled as `ib` is `b`, to within rounding.
    let alike = |ia: u32, a: u32, ib: u32, b: u32| {
        (f64::from(ia) - f64::from(a) * f64::from(ib) / f64::from(b)).abs() <= 0.5
    };
    iw > 0
        && ih > 0
        && iw <= w
        && ih <= h
        && (iw, ih) != (w, h)
        && (alike(iw, w, ih, h) || alike(ih, h, iw, w))
}

impl FrameCtx<'_> {
    fn field(&self, name: &str) -> String {
        format!("frames[{}].{name}", self.index)
    }

    fn json_err(&self, name: &str, problem: Problem) -> DatasetError {
        DatasetError::new(self.json_path, self.field(name), problem)
    }

    fn load(&self, t: &TransformsJson, f: &FrameJson) -> Result<Frame, DatasetError> {
        let intrinsics = self.intrinsics(t, f)?;
        let camera = Camera::from_nerfstudio(intrinsics, &f.transform_matrix)
            .map_err(|e| self.json_err("transform_matrix", Problem::Transform(e)))?;
        let (w, h) = (intrinsics.width, intrinsics.height);

        let (path, img) = self.image("file_path", &f.file_path)?;
        self.same_size(&path, "file_path", &img, (w, h), "the intrinsics (w, h)")?;
        let rgb = img.into_rgb8().into_raw();

        let depth = match &f.depth_file_path {
            None => None,
            Some(rel) => {
                let (path, img) = self.image("depth_file_path", rel)?;
                // A depth map smaller than its photo with the photo's shape (as a
                // reconstruction writes a large photo's) is read at the photo's size, each
                // pixel the nearest one's, as nerfstudio reads it.
                let img = if shrunk(&img, (w, h)) {
                    img.resize_exact(w, h, image::imageops::FilterType::Nearest)
                } else {
                    img
                };
                self.same_size(&path, "depth_file_path", &img, (w, h), "the image")?;
                let raw = self.luma16(&path, "depth_file_path", img)?;
                Some(raw.into_iter().map(|d| (f64::from(d) * self.depth_unit_m) as f32).collect())
            }
        };
        let instances = match &f.instance_file_path {
            None => None,
            Some(rel) => {
                let (path, img) = self.image("instance_file_path", rel)?;
                self.same_size(&path, "instance_file_path", &img, (w, h), "the image")?;
                let ids = self.luma16(&path, "instance_file_path", img)?;
                if let Some(p) = ids.iter().position(|&id| id != 0 && !self.known[id as usize]) {
                    let (x, y) = ((p as u32) % w, (p as u32) / w);
                    let problem = Problem::UnknownInstance { id: ids[p], x, y };
                    return Err(DatasetError::new(path, self.field("instance_file_path"), problem));
                }
                Some(ids)
            }
        };
        Ok(Frame { camera, rgb, depth, instances })
    }

    fn intrinsics(&self, t: &TransformsJson, f: &FrameJson) -> Result<Intrinsics, DatasetError> {
        frame_intrinsics(t, f, self.json_path, self.index)
    }

    /// Resolves `rel` inside the scene folder and decodes it.
    fn image(&self, name: &str, rel: &str) -> Result<(PathBuf, DynamicImage), DatasetError> {
        let p = Path::new(rel);
        if rel.is_empty()
            || p.components().any(|c| !matches!(c, Component::Normal(_) | Component::CurDir))
        {
            return Err(self.json_err(name, Problem::PathEscapes(rel.to_string())));
        }
        let path = self.dir.join(p);
        let field = self.field(name);
        if !path.is_file() {
            return Err(DatasetError::new(path, field, Problem::Missing));
        }
        let img = image::ImageReader::open(&path)
            .and_then(|r| r.with_guessed_format())
            .map_err(|e| Problem::Unreadable(e.to_string()))
            .and_then(|r| r.decode().map_err(|e| Problem::Unreadable(e.to_string())));
        match img {
            Ok(img) => Ok((path, img)),
            Err(problem) => Err(DatasetError::new(path, field, problem)),
        }
    }

    fn same_size(
        &self,
        path: &Path,
        name: &str,
        img: &DynamicImage,
        (w, h): (u32, u32),
        other: &str,
    ) -> Result<(), DatasetError> {
        if (img.width(), img.height()) == (w, h) {
            return Ok(());
        }
        let problem = Problem::SizeMismatch {
            found_w: img.width(),
            found_h: img.height(),
            expected_w: w,
            expected_h: h,
            other: other.to_string(),
        };
        Err(DatasetError::new(path, self.field(name), problem))
    }

    fn luma16(&self, path: &Path, name: &str, img: DynamicImage) -> Result<Vec<u16>, DatasetError> {
        match img {
            DynamicImage::ImageLuma16(buf) => Ok(buf.into_raw()),
            other => {
                let problem = Problem::PixelFormat {
                    expected: "16-bit grayscale",
                    found: format!("{:?}", other.color()),
                };
                Err(DatasetError::new(path, self.field(name), problem))
            }
        }
    }
}

/// Intrinsics of frame `index` (per-frame values, else the top-level ones), checked; errors
/// name `json_path` and the field.
fn frame_intrinsics(
    t: &TransformsJson,
    f: &FrameJson,
    json_path: &Path,
    index: usize,
) -> Result<Intrinsics, DatasetError> {
    let json_err = |name: &str, problem: Problem| {
        DatasetError::new(json_path, format!("frames[{index}].{name}"), problem)
    };
    let float = |name: &str, frame: Option<f64>, top: Option<f64>| -> Result<f32, DatasetError> {
        match frame.or(top) {
            None => Err(json_err(
                name,
                Problem::Invalid(format!("missing (no per-frame or top-level `{name}`)")),
            )),
            Some(v) if !v.is_finite() => {
                Err(json_err(name, Problem::Invalid(format!("{v} is not finite"))))
            }
            Some(v) => Ok(v as f32),
        }
    };
    let size = |name: &str, frame: Option<u32>, top: Option<u32>| -> Result<u32, DatasetError> {
        match frame.or(top) {
            None => Err(json_err(
                name,
                Problem::Invalid(format!("missing (no per-frame or top-level `{name}`)")),
            )),
            Some(0) => Err(json_err(name, Problem::Invalid("image size must be positive".into()))),
            Some(v) => Ok(v),
        }
    };
    let k = Intrinsics {
        fx: float("fl_x", f.fl_x, t.fl_x)?,
        fy: float("fl_y", f.fl_y, t.fl_y)?,
        cx: float("cx", f.cx, t.cx)?,
        cy: float("cy", f.cy, t.cy)?,
        width: size("w", f.w, t.w)?,
        height: size("h", f.h, t.h)?,
    };
    for (name, v) in [("fl_x", k.fx), ("fl_y", k.fy)] {
        if v <= 0.0 {
            return Err(json_err(
                name,
                Problem::Invalid(format!("focal length {v} must be positive")),
            ));
        }
    }
    Ok(k)
}
