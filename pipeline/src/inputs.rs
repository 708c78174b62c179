//! What the CLI accepts as a scene's photos: a folder of images, a dataset scene folder
//! (its `transforms.json` frames, or the context views of its eval split), or image files.
//! Files are read here; decoding and validation happen in the pipeline's decode stage.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use inssplat_proto::dataset::TransformsJson;
use inssplat_proto::signature::MAX_VIEWS;

use crate::reconstruct::InputImage;

const IMAGE_EXTENSIONS: [&str; 5] = ["png", "jpg", "jpeg", "webp", "PNG"];

/// Resolves `paths` to the list of photo files, in order.
pub fn photo_paths(paths: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    match paths {
        [dir] if dir.is_dir() && dir.join("transforms.json").is_file() => dataset_frames(dir),
        [dir] if dir.is_dir() => {
            let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
                .with_context(|| format!("cannot list {}", dir.display()))?
                .flatten()
                .map(|e| e.path())
                .filter(|p| {
                    p.extension()
                        .is_some_and(|e| IMAGE_EXTENSIONS.iter().any(|x| e.eq_ignore_ascii_case(x)))
                })
                .collect();
            files.sort();
            if files.is_empty() {
                bail!("{}: no .png, .jpg or .webp images in this folder", dir.display());
            }
            Ok(files)
        }
        files => {
            for f in files {
                if !f.is_file() {
                    bail!("{}: no such file", f.display());
                }
            }
            Ok(files.to_vec())
        }
    }
}

/// Frames of a dataset scene: the largest context set of its eval split that fits, else
/// up to `MAX_VIEWS` evenly spaced frames.
fn dataset_frames(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let json = dir.join("transforms.json");
    let t = TransformsJson::read(&json)?;
    let n = t.frames.len();
    let chosen: Vec<usize> =
        match t.eval.as_ref().and_then(|e| (2..=MAX_VIEWS).rev().find_map(|v| e.context_for(v))) {
            Some(ctx) => ctx.to_vec(),
            None if n <= MAX_VIEWS => (0..n).collect(),
            None => (0..MAX_VIEWS).map(|i| i * n / MAX_VIEWS).collect(),
        };
    Ok(chosen.into_iter().map(|i| dir.join(&t.frames[i].file_path)).collect())
}

/// Reads the photo files.
pub fn read_photos(paths: &[PathBuf]) -> anyhow::Result<Vec<InputImage>> {
    paths
        .iter()
        .map(|p| {
            let bytes = std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?;
            Ok(InputImage { name: p.display().to_string(), bytes })
        })
        .collect()
}
