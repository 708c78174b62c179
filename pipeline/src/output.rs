//! Writes a reconstruction to a folder: `scene.ply` (standard 3DGS + extras), `images/NNN.*`
//! (the photos it was made from, upright) and `transforms.json` (the cameras, nerfstudio
//! convention, naming those photos relative to itself, so the folder opens as it is in
//! nerfstudio-style tools, gsplat's and brush's loaders); at each photo's resolution (up to the
//! mask size) `instances/NNN.png` and `labels/NNN.png` (a colour per instance / label) and
//! `ids/NNN.png` (the instance ids, 16-bit) and `depth/NNN.png` (16-bit millimetres, named by
//! `transforms.json`); `instances.json` and `preview.png` (input | depth |
//! instances | labels per view, at the model's resolution). Each file is written to a
//! temporary name and renamed, so a crash never leaves a half-written artefact.

use std::path::{Path, PathBuf};

use anyhow::Context;
use image::{Rgb, RgbImage};
use inssplat_proto::api::{
    CameraFit, CameraOut, FocalSource, InstanceOut, Placement, ReconstructResponse, RefinementOut,
};
use inssplat_proto::dataset::{DEFAULT_DEPTH_UNIT_M, FrameJson, TransformsJson};
use inssplat_raster::masks::NO_LABEL;
use serde::{Deserialize, Serialize};

use crate::photo_depth::{depth_png, photo_depth};
use crate::reconstruct::{InputImage, PhotoMaps, Reconstruction, ViewResult};
use crate::stages::decode::portable_photo;

/// A distinct colour for index `i` (golden-angle hues); index 0 is black ("none").
pub fn palette(i: u32) -> [u8; 3] {
    if i == 0 {
        return [0, 0, 0];
    }
    let h = (i as f32 * 137.508).rem_euclid(360.0) / 60.0;
    let (s, v) = (0.65, if i.is_multiple_of(2) { 0.95 } else { 0.75 });
    let c = v * s;
    let x = c * (1.0 - (h % 2.0 - 1.0).abs());
    let (r, g, b) = match h as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    [((r + m) * 255.0) as u8, ((g + m) * 255.0) as u8, ((b + m) * 255.0) as u8]
}

/// Writes `bytes` to `path` atomically (temporary file + rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let tmp = path.with_extension("partial");
    std::fs::write(&tmp, bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path)
        .with_context(|| format!("cannot rename {} to {}", tmp.display(), path.display()))
}

/// `img` (RGB, grey, 8 or 16 bits) encoded as PNG in memory.
pub fn png_bytes<P>(img: &image::ImageBuffer<P, Vec<P::Subpixel>>) -> Vec<u8>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
{
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png)
        .expect("PNG encoding into memory cannot fail");
    bytes.into_inner()
}

/// Encodes `img` as PNG and writes it atomically.
pub fn save_png(path: &Path, img: &RgbImage) -> anyhow::Result<()> {
    write_atomic(path, &png_bytes(img))
}

/// An id or label map coloured by `colour`.
pub fn colour_map(
    width: u32,
    height: u32,
    values: &[u32],
    colour: impl Fn(u32) -> [u8; 3],
) -> RgbImage {
    RgbImage::from_fn(width, height, |x, y| Rgb(colour(values[(y * width + x) as usize])))
}

/// A view's instance ids as a 16-bit grey PNG (ids past 65535 saturate).
fn id_png(m: &PhotoMaps) -> Vec<u8> {
    png_bytes(&image::ImageBuffer::<image::Luma<u16>, _>::from_fn(m.width, m.height, |x, y| {
        image::Luma([m.instance_ids[(y * m.width + x) as usize].min(u32::from(u16::MAX)) as u16])
    }))
}

/// A view's depth as `depth/NNN.png` holds it: at the size of its masks over the photo, or
/// the photo at the model's scale when they have none.
fn view_depth_png(v: &ViewResult) -> Vec<u8> {
    let lb = &v.letterbox;
    let size = match &v.photo_maps {
        Some(m) => (m.width, m.height),
        None => {
            let side = |n: u32| ((n as f32 * lb.scale).round() as u32).max(1);
            (side(lb.width), side(lb.height))
        }
    };
    depth_png(size.0, size.1, &photo_depth(&v.depth, lb, size))
}

/// Depth as grey, near = bright, scaled by the 2–98 percentile range of the view.
fn depth_image(width: u32, height: u32, depth: &[f32]) -> RgbImage {
    let mut sorted: Vec<f32> =
        depth.iter().copied().filter(|d| d.is_finite() && *d > 0.0).collect();
    sorted.sort_by(f32::total_cmp);
    let pick = |q: f32| {
        sorted.get(((sorted.len().max(1) - 1) as f32 * q) as usize).copied().unwrap_or(1.0)
    };
    let (lo, hi) = (pick(0.02), pick(0.98).max(pick(0.02) + 1e-6));
    RgbImage::from_fn(width, height, |x, y| {
        let d = depth[(y * width + x) as usize];
        let v = if d > 0.0 {
            (255.0 * (1.0 - ((d - lo) / (hi - lo)).clamp(0.0, 1.0))) as u8
        } else {
            0
        };
        Rgb([v, v, v])
    })
}

/// The `instances.json` document.
#[derive(Debug, Serialize, Deserialize)]
pub struct InstancesDoc {
    pub instances: Vec<InstanceOut>,
    pub vocabulary: Vec<String>,
    /// Colour of each instance id in `instances/NNN.png` and of each label in `labels/NNN.png`.
    pub instance_colours: Vec<(u32, [u8; 3])>,
    pub label_colours: Vec<(String, [u8; 3])>,
    /// Each instance's semantic prototype in the text-embedding space (what `inssplat query`
    /// compares query text with).
    pub prototypes: Vec<PrototypeOut>,
}

/// One instance's semantic prototype.
#[derive(Debug, Serialize, Deserialize)]
pub struct PrototypeOut {
    pub id: u32,
    pub embedding: Vec<f32>,
    pub gaussians: usize,
}

/// The predicted cameras, nerfstudio convention, in the input photos' pixel units.
pub fn cameras_out(rec: &Reconstruction) -> Vec<CameraOut> {
    rec.views
        .iter()
        .enumerate()
        .map(|(view, v)| {
            let k = v.letterbox.to_original(&v.camera.intrinsics);
            CameraOut {
                view,
                transform_matrix: v.camera.to_nerfstudio(),
                fl_x: k.fx,
                fl_y: k.fy,
                cx: k.cx,
                cy: k.cy,
                w: k.width,
                h: k.height,
                placement: Some(v.placement),
                focal: Some(v.focal),
                fit: v.fit.map(|f| CameraFit {
                    reprojection_px: f.reprojection_px.map(|e| e / v.letterbox.scale),
                    ..f
                }),
            }
        })
        .collect()
}

/// Writes every artefact of `rec`, made from `photos`, into `out`. Returns the paths written.
pub fn write_reconstruction(
    rec: &Reconstruction,
    photos: &[InputImage],
    out: &Path,
) -> anyhow::Result<Vec<PathBuf>> {
    for sub in ["images", "depth", "ids", "instances", "labels"] {
        std::fs::create_dir_all(out.join(sub))
            .with_context(|| format!("cannot create {}", out.join(sub).display()))?;
    }
    let mut written = Vec::new();
    let mut ply = Vec::new();
    inssplat_proto::ply::write_ply(&mut ply, &rec.scene)?;
    let path = out.join("scene.ply");
    write_atomic(&path, &ply)?;
    written.push(path);

    let mut names = Vec::with_capacity(photos.len());
    for (i, (photo, v)) in photos.iter().zip(&rec.views).enumerate() {
        let (bytes, ext) = portable_photo(&photo.name, &photo.bytes)?;
        let name = format!("images/{i:03}.{ext}");
        let path = out.join(&name);
        write_atomic(&path, &bytes)?;
        written.push(path);
        let depth_name = format!("depth/{i:03}.png");
        let path = out.join(&depth_name);
        write_atomic(&path, &view_depth_png(v))?;
        written.push(path);
        names.push((name, depth_name));
    }
    let frames = cameras_out(rec)
        .into_iter()
        .zip(names)
        .map(|(c, (file_path, depth_file_path))| FrameJson {
            file_path,
            depth_file_path: Some(depth_file_path),
            instance_file_path: None,
            transform_matrix: c.transform_matrix,
            fl_x: Some(f64::from(c.fl_x)),
            fl_y: Some(f64::from(c.fl_y)),
            cx: Some(f64::from(c.cx)),
            cy: Some(f64::from(c.cy)),
            w: Some(c.w),
            h: Some(c.h),
        })
        .collect();
    let transforms = TransformsJson {
        camera_model: "OPENCV".into(),
        fl_x: None,
        fl_y: None,
        cx: None,
        cy: None,
        w: None,
        h: None,
        depth_unit_m: Some(DEFAULT_DEPTH_UNIT_M),
        instances: Vec::new(),
        frames,
        eval: None,
    };
    let path = out.join("transforms.json");
    write_atomic(&path, serde_json::to_string_pretty(&transforms)?.as_bytes())?;
    written.push(path);

    let mut sheet_rows = Vec::new();
    let label_colour = |l: u32| if l == NO_LABEL { [0, 0, 0] } else { palette(l + 1) };
    for (i, v) in rec.views.iter().enumerate() {
        let (w, h) = (v.camera.intrinsics.width, v.camera.intrinsics.height);
        let inst = colour_map(w, h, &v.instance_ids, palette);
        let labels = colour_map(w, h, &v.labels, label_colour);
        let maps = match &v.photo_maps {
            Some(m) => {
                let path = out.join("ids").join(format!("{i:03}.png"));
                write_atomic(&path, &id_png(m))?;
                written.push(path);
                [
                    ("instances", colour_map(m.width, m.height, &m.instance_ids, palette)),
                    ("labels", colour_map(m.width, m.height, &m.labels, label_colour)),
                ]
            }
            None => [("instances", inst.clone()), ("labels", labels.clone())],
        };
        for (dir, img) in &maps {
            let path = out.join(dir).join(format!("{i:03}.png"));
            save_png(&path, img)?;
            written.push(path);
        }
        let rgb = RgbImage::from_raw(w, h, v.rgb.clone()).context("view image size")?;
        sheet_rows.push([rgb, depth_image(w, h, &v.depth), inst, labels]);
    }
    let path = out.join("preview.png");
    save_png(&path, &contact_sheet(&sheet_rows))?;
    written.push(path);

    let doc = InstancesDoc {
        instances: rec.instances.clone(),
        vocabulary: rec.vocabulary.clone(),
        instance_colours: rec.instances.iter().map(|i| (i.id, palette(i.id))).collect(),
        label_colours: rec
            .vocabulary
            .iter()
            .enumerate()
            .map(|(l, name)| (name.clone(), palette(l as u32 + 1)))
            .collect(),
        prototypes: rec
            .prototypes
            .iter()
            .map(|p| PrototypeOut {
                id: p.id,
                embedding: p.embedding.clone(),
                gaussians: p.gaussians,
            })
            .collect(),
    };
    let path = out.join("instances.json");
    write_atomic(&path, serde_json::to_string_pretty(&doc)?.as_bytes())?;
    written.push(path);
    Ok(written)
}

/// The result as the CLI's `--json` prints it (the HTTP response shape without a scene id).
pub fn summary(rec: &Reconstruction) -> ReconstructResponse {
    let cameras = cameras_out(rec);
    ReconstructResponse {
        scene_id: String::new(),
        warnings: crate::warnings::warnings(rec, &cameras),
        cameras,
        instances: rec.instances.clone(),
        timings: rec.timings.clone(),
        gaussians_in: rec.voxel.gaussians_in,
        gaussians_kept: rec.voxel.gaussians_out,
        refinement: rec.refinement.as_ref().map(|r| {
            let [input_psnr_before, input_psnr_after] = r.psnr();
            RefinementOut {
                steps: r.steps,
                input_psnr_before,
                input_psnr_after,
                photo_gains: r.gains.clone(),
            }
        }),
    }
}

/// A few lines for people: what was found, how long each stage took, where the files are.
pub fn describe(s: &ReconstructResponse, out: &Path) -> String {
    let mut text = format!(
        "{} views → {} Gaussians kept of {} ({} instances)\n",
        s.cameras.len(),
        s.gaussians_kept,
        s.gaussians_in,
        s.instances.len()
    );
    for i in &s.instances {
        text.push_str(&format!(
            "  #{:<3} {:<20} score {:.2}  {} Gaussians\n",
            i.id, i.label, i.score, i.gaussians
        ));
    }
    text.push_str(&describe_cameras(&s.cameras));
    for w in &s.warnings {
        text.push_str(&format!("warning: {w}\n"));
    }
    if let Some(r) = &s.refinement {
        text.push_str(&format!(
            "refined against the photos for {} steps: input views {:.2} → {:.2} dB PSNR; photos' gains {}\n",
            r.steps,
            r.input_psnr_before,
            r.input_psnr_after,
            r.photo_gains.iter().map(|g| format!("{g:.2}")).collect::<Vec<_>>().join(" ")
        ));
    }
    let total: f64 = s.timings.iter().map(|t| t.ms).sum();
    let stages: Vec<String> =
        s.timings.iter().map(|t| format!("{} {:.0} ms", t.stage, t.ms)).collect();
    text.push_str(&format!("time {total:.0} ms: {}\n", stages.join(", ")));
    text.push_str(&format!(
        "outputs in {} (scene.ply, transforms.json, images/, depth/, ids/, instances/, labels/, \
         instances.json, preview.png)",
        out.display()
    ));
    text
}

/// One line on the cameras: which views registration linked to the first, which it placed
/// otherwise, and the field of view.
fn describe_cameras(cameras: &[CameraOut]) -> String {
    let views = |p: Placement| -> String {
        let list: Vec<String> =
            cameras.iter().filter(|c| c.placement == Some(p)).map(|c| c.view.to_string()).collect();
        match list.len() {
            0 => String::new(),
            1 => format!("view {}", list[0]),
            _ => format!("views {}", list.join(", ")),
        }
    };
    let linked = cameras
        .iter()
        .filter(|c| matches!(c.placement, Some(Placement::Reference | Placement::Registered)))
        .count();
    let mut parts = vec![format!("{linked} of {} views registered to view 0", cameras.len())];
    let continued = views(Placement::Continued);
    if !continued.is_empty() {
        parts.push(format!("{continued} placed by continuing the camera's motion, then turned to the heading the photos before them match best (no keypoint match links them)"));
    }
    let head = views(Placement::CameraHead);
    if !head.is_empty() {
        parts.push(format!("{head} at the camera head's pose"));
    }
    if cameras.iter().all(|c| c.placement == Some(Placement::Given)) {
        parts = vec![format!("{} views at the given poses", cameras.len())];
    }
    if let Some(c) = cameras.first() {
        let source = match c.focal {
            Some(FocalSource::Measured) => " (measured from the matches)",
            Some(FocalSource::CameraHead) => {
                " (the camera head's guess: the matches do not pin it down)"
            }
            Some(FocalSource::Given) => " (given)",
            Some(FocalSource::Exif) => " (from the photo's EXIF)",
            None => "",
        };
        parts.push(format!(
            "field of view {:.1}°{source}",
            (2.0 * (0.5 * c.h as f32 / c.fl_y).atan()).to_degrees()
        ));
    }
    format!("cameras: {}\n", parts.join("; "))
}

/// Rows of equally sized tiles, 2-pixel gaps, white background.
fn contact_sheet(rows: &[[RgbImage; 4]]) -> RgbImage {
    let (tw, th) = rows.first().map_or((1, 1), |r| r[0].dimensions());
    let gap = 2;
    let mut sheet = RgbImage::from_pixel(
        4 * (tw + gap) + gap,
        rows.len() as u32 * (th + gap) + gap,
        Rgb([255, 255, 255]),
    );
    for (r, row) in rows.iter().enumerate() {
        for (c, tile) in row.iter().enumerate() {
            image::imageops::overlay(
                &mut sheet,
                tile,
                i64::from(gap + c as u32 * (tw + gap)),
                i64::from(gap + r as u32 * (th + gap)),
            );
        }
    }
    sheet
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn palette_is_distinct_for_nearby_ids_and_black_for_none() {
        assert_eq!(palette(0), [0, 0, 0]);
        let colours: Vec<_> = (1..=24).map(palette).collect();
        for (i, a) in colours.iter().enumerate() {
            for b in &colours[i + 1..] {
                assert_ne!(a, b);
            }
        }
    }

    #[test]
    fn atomic_write_leaves_no_partial_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.json");
        write_atomic(&p, b"{}").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"{}");
        assert!(!dir.path().join("x.partial").exists());
    }
}
