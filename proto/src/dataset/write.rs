//! Writing a scene folder: PNG images, 16-bit depth quantized by `depth_unit_m`, 16-bit
//! instance masks and `transforms.json`. Output is a pure function of the scene, so equal
//! scenes give byte-identical folders.

use std::path::Path;

use image::{ImageBuffer, Luma, Rgb};

use super::error::{DatasetError, Problem};
use super::transforms::{FrameJson, TransformsJson};
use super::{Frame, Scene};

impl Scene {
    /// The `transforms.json` content of this scene. Intrinsics of frame 0 go to the top
    /// level; a frame whose intrinsics differ carries its own.
    pub fn transforms_json(&self) -> TransformsJson {
        let k0 = self.frames.first().map(|f| f.camera.intrinsics);
        let frames = self
            .frames
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let k = f.camera.intrinsics;
                let own = Some(k) != k0;
                let pick = |v: f32| own.then_some(f64::from(v));
                FrameJson {
                    file_path: format!("images/{i:03}.png"),
                    depth_file_path: f.depth.as_ref().map(|_| format!("depth/{i:03}.png")),
                    instance_file_path: f
                        .instances
                        .as_ref()
                        .map(|_| format!("instances/{i:03}.png")),
                    transform_matrix: f.camera.to_nerfstudio(),
                    fl_x: pick(k.fx),
                    fl_y: pick(k.fy),
                    cx: pick(k.cx),
                    cy: pick(k.cy),
                    w: own.then_some(k.width),
                    h: own.then_some(k.height),
                }
            })
            .collect();
        TransformsJson {
            camera_model: "OPENCV".into(),
            fl_x: k0.map(|k| f64::from(k.fx)),
            fl_y: k0.map(|k| f64::from(k.fy)),
            cx: k0.map(|k| f64::from(k.cx)),
            cy: k0.map(|k| f64::from(k.cy)),
            w: k0.map(|k| k.width),
            h: k0.map(|k| k.height),
            depth_unit_m: Some(self.depth_unit_m),
            instances: self.instances.clone(),
            frames,
            eval: self.eval.clone(),
        }
    }

    /// Writes the scene into `dir` (created if needed).
    pub fn write(&self, dir: impl AsRef<Path>) -> Result<(), DatasetError> {
        let dir = dir.as_ref();
        for sub in ["images", "depth", "instances"] {
            let p = dir.join(sub);
            std::fs::create_dir_all(&p).map_err(|e| write_err(&p, e))?;
        }
        for (i, f) in self.frames.iter().enumerate() {
            self.write_frame(dir, i, f)?;
        }
        let path = dir.join("transforms.json");
        let text = serde_json::to_string_pretty(&self.transforms_json())
            .map_err(|e| DatasetError::new(&path, "(document)", Problem::Invalid(e.to_string())))?;
        std::fs::write(&path, text).map_err(|e| write_err(&path, e))
    }

    fn write_frame(&self, dir: &Path, i: usize, f: &Frame) -> Result<(), DatasetError> {
        let (w, h) = (f.width(), f.height());
        let path = dir.join(format!("images/{i:03}.png"));
        let img = ImageBuffer::<Rgb<u8>, _>::from_raw(w, h, f.rgb.clone())
            .ok_or_else(|| size_err(&path, i, "rgb", f.rgb.len(), 3 * w * h))?;
        img.save(&path).map_err(|e| write_err(&path, e))?;
        if let Some(depth) = &f.depth {
            let path = dir.join(format!("depth/{i:03}.png"));
            let q: Vec<u16> = depth.iter().map(|&d| quantize(d, self.depth_unit_m)).collect();
            save_l16(&path, w, h, q)
                .ok_or_else(|| size_err(&path, i, "depth", depth.len(), w * h))??;
        }
        if let Some(ids) = &f.instances {
            let path = dir.join(format!("instances/{i:03}.png"));
            save_l16(&path, w, h, ids.clone())
                .ok_or_else(|| size_err(&path, i, "instances", ids.len(), w * h))??;
        }
        Ok(())
    }
}

/// Metres → depth quantum, 0 (no hit) for non-finite or non-positive depth.
fn quantize(d: f32, unit: f64) -> u16 {
    if d.is_finite() && d > 0.0 {
        (f64::from(d) / unit).round().clamp(1.0, f64::from(u16::MAX)) as u16
    } else {
        0
    }
}

fn save_l16(path: &Path, w: u32, h: u32, data: Vec<u16>) -> Option<Result<(), DatasetError>> {
    let img = ImageBuffer::<Luma<u16>, _>::from_raw(w, h, data)?;
    Some(img.save(path).map_err(|e| write_err(path, e)))
}

fn write_err(path: &Path, e: impl std::fmt::Display) -> DatasetError {
    DatasetError::new(path, "(file)", Problem::Unreadable(format!("cannot write: {e}")))
}

fn size_err(path: &Path, i: usize, what: &str, len: usize, expected: u32) -> DatasetError {
    let problem = Problem::Invalid(format!("{len} values for a frame that needs {expected}"));
    DatasetError::new(path, format!("frames[{i}].{what}"), problem)
}
