//! `inssplat render OUT --camera ...`: a saved reconstruction seen from new cameras, as RGB,
//! instance-colour and label-colour images (`rgb_NNN.png`, `instances_NNN.png`,
//! `labels_NNN.png`). Cameras come from a `transforms.json` (nerfstudio convention, e.g. one
//! edited by hand or exported by another tool) or from `interp:i,j,t`, the pose a fraction t
//! of the way from input view i to input view j (centres lerped, rotations slerped, the
//! intrinsics of view i). The instance masks render on a GPU where one is asked for. What no
//! Gaussian covers is filled from around it (`--no-fill` keeps the raw renders).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use image::{Rgb, RgbImage};
use inssplat_proto::Camera;
use inssplat_proto::dataset::TransformsJson;
use inssplat_raster::masks::NO_LABEL;
use inssplat_raster::masks::{fill_uncovered, label_map, render_colour, render_instance_ids_on};
use inssplat_raster::render::{Backend, GpuRenderer};

use crate::output::{colour_map, palette, save_png};
use crate::reconstruct::label_table;
use crate::saved::Saved;

/// Parses `--camera`: `interp:i,j,t` or a path to a transforms.json.
pub fn cameras(saved: &Saved, spec: &str) -> anyhow::Result<Vec<Camera>> {
    if let Some(args) = spec.strip_prefix("interp:") {
        let parts: Vec<&str> = args.split(',').map(str::trim).collect();
        let [i, j, t] = parts.as_slice() else { bail!("--camera {spec}: expected interp:i,j,t") };
        let view = |s: &str| -> anyhow::Result<usize> {
            let v: usize =
                s.parse().with_context(|| format!("--camera {spec}: `{s}` is not a view index"))?;
            if v >= saved.cameras.len() {
                bail!(
                    "--camera {spec}: view {v} does not exist (the reconstruction has {} views)",
                    saved.cameras.len()
                );
            }
            Ok(v)
        };
        let (a, b) = (saved.cameras[view(i)?], saved.cameras[view(j)?]);
        let t: f32 =
            t.parse().with_context(|| format!("--camera {spec}: `{t}` is not a number"))?;
        if !(0.0..=1.0).contains(&t) {
            bail!("--camera {spec}: t = {t} is outside 0-1");
        }
        let rotation = a.rotation.slerp(b.rotation, t).normalize();
        let centre = a.center().lerp(b.center(), t);
        return Ok(vec![Camera {
            intrinsics: a.intrinsics,
            rotation,
            translation: -(rotation * centre),
        }]);
    }
    let path = Path::new(spec);
    let t = TransformsJson::read(path)
        .with_context(|| format!("--camera {spec}: give a transforms.json or interp:i,j,t"))?;
    Ok(t.cameras(path)?)
}

/// Renders every camera into `out`, the instance masks on `gpu` when given (the CPU if it
/// fails), with what no Gaussian covers filled from around it unless `fill` is off
/// ([`inssplat_raster::fill`]); returns the files written and where the masks were rendered (the
/// CPU if any view's
/// were).
pub fn render_views(
    saved: &Saved,
    cameras: &[Camera],
    out: &Path,
    gpu: Option<&GpuRenderer>,
    fill: bool,
) -> anyhow::Result<(Vec<PathBuf>, Backend)> {
    std::fs::create_dir_all(out).with_context(|| format!("-o: cannot create {}", out.display()))?;
    let label_of_id = label_table(&saved.doc.instances, &saved.doc.vocabulary);
    let k = label_of_id.len();
    let mut written = Vec::new();
    let mut backend = Backend::Wgpu;
    for (v, camera) in cameras.iter().enumerate() {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let pixels = (w * h) as usize;
        let colour = render_colour(&saved.scene, camera, fill)?;
        let rgb = RgbImage::from_fn(w, h, |x, y| {
            let p = (y * w + x) as usize;
            Rgb([0, 1, 2].map(|c| (colour[c * pixels + p].clamp(0.0, 1.0) * 255.0).round() as u8))
        });
        let (mut ids, used) = render_instance_ids_on(gpu, &saved.scene, camera, k)?;
        if used == Backend::Cpu {
            backend = Backend::Cpu;
        }
        let mut labels = label_map(&ids, &label_of_id);
        if fill {
            fill_uncovered(&mut ids, Some(&mut labels), w as usize, h as usize);
        }
        let images =
            [
                ("rgb", rgb),
                ("instances", colour_map(w, h, &ids, palette)),
                (
                    "labels",
                    colour_map(w, h, &labels, |l| {
                        if l == NO_LABEL { [0, 0, 0] } else { palette(l + 1) }
                    }),
                ),
            ];
        for (kind, img) in images {
            let path = out.join(format!("{kind}_{v:03}.png"));
            save_png(&path, &img)?;
            written.push(path);
        }
    }
    Ok((written, if cameras.is_empty() { Backend::Cpu } else { backend }))
}
