//! Photos that registration cannot place well, through the real binary with the shipped network
//! and the shipped learned matcher: a flat photo, a photo sent twice, a photo of something
//! else, a photo turned 90° (by its pixels, or by an EXIF orientation that lies), photos under-
//! and over-exposed. Each gives a reconstruction whose
//! cameras say honestly how they were placed, with a warning naming the view where its pose is
//! a guess; none panics.

use std::path::{Path, PathBuf};

use crate::support::photo::save_jpeg_with_exif;
use crate::support::s;
use image::RgbImage;
use inssplat_e2e::inssplat;
use inssplat_proto::api::{Placement, ReconstructResponse};
use inssplat_proto::dataset::Scene;
use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};

struct Case {
    _dir: tempfile::TempDir,
    photos: Vec<PathBuf>,
    root: PathBuf,
}

/// The 8 context photos of test scene 0, written as PNG files.
fn case() -> Case {
    let dir = tempfile::tempdir().unwrap();
    let cfg = SynthConfig::new(Split::Test, Furniture::from_env());
    let scene_dir = dir.path().join("scene");
    synth::generate_split(0, &cfg).unwrap().write(&scene_dir).unwrap();
    let scene = Scene::load(&scene_dir).unwrap();
    let context = scene.eval.as_ref().and_then(|e| e.context_for(8)).unwrap().to_vec();
    let photos = context.iter().map(|f| scene_dir.join(format!("images/{f:03}.png"))).collect();
    Case { root: dir.path().to_path_buf(), _dir: dir, photos }
}

impl Case {
    /// Photo `v` as a JPEG whose EXIF says to turn it a quarter clockwise, though it is upright.
    fn lying_orientation(&mut self, v: usize) {
        let photo = image::open(&self.photos[v]).unwrap().to_rgb8();
        let path = self.root.join(format!("lying{v}.jpg"));
        let turn = (exif::Tag::Orientation, exif::Value::Short(vec![6]));
        save_jpeg_with_exif(&photo, &[turn], &path);
        self.photos[v] = path;
    }

    /// Photo `v` replaced by `edit` of it, written beside the scene.
    fn edit(&mut self, v: usize, edit: impl Fn(RgbImage) -> RgbImage) {
        let photo = image::open(&self.photos[v]).unwrap().to_rgb8();
        let path = self.root.join(format!("edited{v}.png"));
        edit(photo).save(&path).unwrap();
        self.photos[v] = path;
    }

    fn reconstruct(&self) -> ReconstructResponse {
        let out = self.root.join("out");
        let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx");
        let mut args: Vec<&str> = vec!["reconstruct"];
        args.extend(self.photos.iter().map(|p| s(p)));
        args.extend(["-o", s(&out), "--model", s(&model), "--json"]);
        let run = inssplat(&args);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        serde_json::from_slice(&run.stdout).unwrap()
    }
}

fn warned(r: &ReconstructResponse, needle: &str) -> bool {
    r.warnings.iter().any(|w| w.contains(needle))
}

#[test]
fn untouched_photos_are_all_registered_without_warnings() {
    let r = case().reconstruct();
    assert!(r.cameras.iter().skip(1).all(|c| c.placement == Some(Placement::Registered)));
    for c in &r.cameras {
        let fit = c.fit.expect("registration reports its fit");
        assert!(fit.keypoints >= 100 && fit.matches >= 20, "view {}: {fit:?}", c.view);
        assert!(fit.reprojection_px.is_some_and(|e| e < 4.0), "view {}: {fit:?}", c.view);
    }
    assert!(r.warnings.is_empty(), "{:?}", r.warnings);
}

#[test]
fn a_flat_photo_is_left_unregistered_and_named() {
    let mut c = case();
    c.edit(3, |p| RgbImage::from_pixel(p.width(), p.height(), image::Rgb([128, 128, 128])));
    let r = c.reconstruct();
    assert_ne!(r.cameras[3].placement, Some(Placement::Registered));
    assert!(warned(&r, "view 3: no keypoint match links it"), "{:?}", r.warnings);
    assert!(warned(&r, "too little texture"), "{:?}", r.warnings);
}

#[test]
fn a_photo_sent_twice_is_named() {
    let mut c = case();
    c.photos[5] = c.photos[4].clone();
    let r = c.reconstruct();
    assert!(warned(&r, "views 4 and 5 are the same photo"), "{:?}", r.warnings);
}

#[test]
fn a_photo_of_something_else_is_not_registered() {
    let mut c = case();
    let other = std::env::var_os("INSSPLAT_PHOTOS_DIR")
        .map(PathBuf::from)
        .expect("INSSPLAT_PHOTOS_DIR (set by `source .deps/env` after scripts/setup)");
    c.photos[6] = other.join("motorcycle/motorcycle_left.png");
    let r = c.reconstruct();
    assert_ne!(r.cameras[6].placement, Some(Placement::Registered), "{:?}", r.cameras[6]);
    assert!(warned(&r, "view 6: no keypoint match links it"), "{:?}", r.warnings);
}

#[test]
fn a_turned_photo_and_badly_exposed_ones_are_placed_or_named() {
    let mut c = case();
    c.edit(2, |p| image::imageops::rotate90(&p));
    c.edit(4, |mut p| {
        p.pixels_mut().for_each(|px| px.0 = px.0.map(|v| (f32::from(v) * 0.3) as u8));
        p
    });
    c.edit(5, |mut p| {
        p.pixels_mut().for_each(|px| px.0 = px.0.map(|v| (f32::from(v) * 2.0).min(255.0) as u8));
        p
    });
    let upright = image::open(&c.photos[6]).unwrap().to_rgb8();
    c.lying_orientation(6);
    let r = c.reconstruct();
    // The photo is read as its EXIF says (turned), and the output folder keeps it so.
    let copy = image::open(c.root.join("out/images/006.png")).unwrap().to_rgb8();
    let differs = |a: &RgbImage, b: &RgbImage| {
        let sum: u64 =
            a.as_raw().iter().zip(b.as_raw()).map(|(x, y)| u64::from(x.abs_diff(*y))).sum();
        sum as f64 / a.as_raw().len() as f64
    };
    let turned = image::imageops::rotate90(&upright);
    assert!(differs(&copy, &turned) < 4.0 && differs(&copy, &upright) > 20.0, "view 6 not turned");
    for v in [2, 4, 5, 6] {
        let placed = r.cameras[v].placement == Some(Placement::Registered);
        let named = warned(&r, &format!("view {v}: "));
        assert!(placed || named, "view {v}: {:?}, warnings {:?}", r.cameras[v], r.warnings);
    }
    // Exposure changes a photo's brightness, not what it shows: the learned matcher links it.
    assert_eq!(r.cameras[4].placement, Some(Placement::Registered), "{:?}", r.cameras[4]);
}
