//! A user's own photos through the real binary with the shipped network, from the real photo
//! sets `scripts/setup` unpacks into `$INSSPLAT_PHOTOS_DIR` (one folder per scene). Every set
//! reconstructs, with its depth, masks and ids at its photos' size. The Middlebury motorcycle
//! and aloe stereo pairs, saved as a phone would (JPEG with the 35 mm-equivalent focal length in
//! its EXIF), take that focal length and their baselines' direction; the motorcycle's depth is
//! scored against its true disparity; its masks come back at the photos' resolution, and the
//! output folder holds the photos its `transforms.json` names.

use std::path::{Path, PathBuf};

use image::RgbImage;

use crate::support::photo::save_jpeg_with_exif;
use crate::support::s;
use inssplat_e2e::{inssplat, inssplat_eval};
use inssplat_proto::api::{
    CameraOut, FocalSource, NamedBy, Placement, QueryResponse, ReconstructResponse,
};

/// The motorcycle pair's focal length, 995 px (Middlebury 2014's calibration, scaled to
/// 741 px), as the 35 mm-equivalent EXIF field gives it: whole millimetres.
const MOTORCYCLE_35MM: u16 = 48;

/// The aloe pair's, 3740 px at 1282×1110 (Middlebury 2006).
const ALOE_35MM: u16 = 95;

fn photos_dir() -> PathBuf {
    std::env::var_os("INSSPLAT_PHOTOS_DIR")
        .map(PathBuf::from)
        .expect("INSSPLAT_PHOTOS_DIR (set by `source .deps/env` after scripts/setup)")
}

/// `photo` as a JPEG in `dir` whose EXIF says a `focal_35mm` mm-equivalent lens took it.
fn with_exif(photo: &Path, dir: &Path, focal_35mm: u16) -> PathBuf {
    let rgb = image::open(photo).unwrap().to_rgb8();
    let path = dir.join(photo.with_extension("jpg").file_name().unwrap());
    let focal = (exif::Tag::FocalLengthIn35mmFilm, exif::Value::Short(vec![focal_35mm]));
    save_jpeg_with_exif(&rgb, &[focal], &path);
    path
}

/// Runs `inssplat reconstruct` on `photos` into `out` with the shipped model.
fn reconstruct(photos: &[PathBuf], out: &Path) -> ReconstructResponse {
    reconstruct_with(photos, out, &[])
}

/// [`reconstruct`] with `extra` switches.
fn reconstruct_with(photos: &[PathBuf], out: &Path, extra: &[&str]) -> ReconstructResponse {
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx");
    let mut args: Vec<&str> = vec!["reconstruct"];
    args.extend(photos.iter().map(|p| s(p)));
    args.extend(["-o", s(out), "--model", s(&model), "--json"]);
    args.extend(extra);
    let run = inssplat(&args);
    assert!(run.status.success(), "{photos:?}: {}", String::from_utf8_lossy(&run.stderr));
    serde_json::from_slice(&run.stdout).unwrap()
}

/// How far, in degrees, the second camera lies from the first camera's x axis (a rectified
/// pair's baseline; nerfstudio axes, the world the first camera's), as the answer gives it.
fn sideways_off(r: &ReconstructResponse) -> f64 {
    let m = &r.cameras[1].transform_matrix;
    let step = glam::DVec3::new(m[0][3], m[1][3], m[2][3]);
    step.normalize().dot(glam::DVec3::X).acos().to_degrees()
}

/// The same, and the first view's depth AbsRel against `disparity`, as `inssplat-eval stereo`
/// scores them from the output folder `out`.
fn stereo_score(out: &Path, disparity: &Path, doffs: f64) -> (f64, f64) {
    let run = inssplat_eval(&[
        "stereo",
        s(out),
        "--disparity",
        s(disparity),
        "--doffs",
        &doffs.to_string(),
        "--json",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    (v["baseline_off_deg"].as_f64().unwrap(), v["abs_rel"].as_f64().unwrap())
}

fn registered(c: &CameraOut) -> bool {
    matches!(c.placement, Some(Placement::Registered | Placement::Reference))
}

#[test]
fn every_real_photo_set_reconstructs_with_its_depth_and_masks_at_its_photos_size() {
    let dir = tempfile::tempdir().unwrap();
    let mut sets: Vec<PathBuf> = std::fs::read_dir(photos_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir() && !p.ends_with("truth"))
        .collect();
    sets.sort();
    let names: Vec<_> = sets.iter().map(|p| p.file_name().unwrap().to_owned()).collect();
    assert_eq!(names, ["aloe", "books", "castel", "cube", "leuven", "motorcycle", "street"]);
    for set in &sets {
        let mut photos: Vec<PathBuf> = std::fs::read_dir(set)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.file_name().is_some_and(|n| !n.to_string_lossy().starts_with('.')))
            .collect();
        photos.sort();
        // ViSP's frames are grey PGM, which the service does not read: sent as PNG.
        for p in photos.iter_mut().filter(|p| p.extension().is_some_and(|e| e == "pgm")) {
            let png = dir.path().join(p.with_extension("png").file_name().unwrap());
            image::open(&*p).unwrap().save(&png).unwrap();
            *p = png;
        }
        let out = dir.path().join(set.file_name().unwrap());
        let r = reconstruct(&photos, &out);
        assert_eq!(r.cameras.len(), photos.len(), "{set:?}");
        for (v, (c, photo)) in r.cameras.iter().zip(&photos).enumerate() {
            let (w, h) = image::image_dimensions(photo).unwrap();
            assert_eq!((c.w, c.h), (w, h), "{photo:?}");
            // Registered (or the reference), or the user is told that its pose is a guess.
            let warned = r.warnings.iter().any(|w| w.starts_with(&format!("view {v}:")));
            assert!(registered(c) || warned, "{photo:?}: {c:?}");
            // Depth and ids at the photo's size, up to the default mask size's long side of
            // 1024.
            let scale = (1024.0 / w.max(h) as f32).min(1.0);
            let size = ((w as f32 * scale).round() as u32, (h as f32 * scale).round() as u32);
            let depth = image::open(out.join(format!("depth/{v:03}.png"))).unwrap().into_luma16();
            assert_eq!(depth.dimensions(), size, "{photo:?}");
            let covered = depth.pixels().filter(|p| p[0] > 0).count();
            let all = (size.0 * size.1) as usize;
            assert!(covered > all * 9 / 10, "{photo:?}: depth at {covered} of {all} pixels");
            let ids = image::open(out.join(format!("ids/{v:03}.png"))).unwrap();
            assert_eq!((ids.width(), ids.height()), size, "{photo:?}");
        }
        // All of a set's views but the leuven pair's (too far apart for a match) register.
        if !set.ends_with("leuven") {
            assert!(r.cameras.iter().all(registered), "{set:?}: {:?}", r.warnings);
        }
    }
}

#[test]
fn landscape_and_portrait_photos_in_one_request_keep_their_own_shapes() {
    // Four of ViSP's castel frames (640×480), one cut to a portrait 300×480 of its middle.
    let dir = tempfile::tempdir().unwrap();
    let frames = ["image_0000.pgm", "image_0004.pgm", "image_0008.pgm", "image_0012.pgm"];
    let photos: Vec<PathBuf> = frames
        .iter()
        .enumerate()
        .map(|(v, f)| {
            let mut img = image::open(photos_dir().join("castel").join(f)).unwrap();
            if v == 2 {
                img = img.crop_imm(170, 0, 300, 480);
            }
            let path = dir.path().join(format!("{v}.png"));
            img.save(&path).unwrap();
            path
        })
        .collect();
    let out = dir.path().join("out");
    let r = reconstruct(&photos, &out);
    for (v, c) in r.cameras.iter().enumerate() {
        let size = if v == 2 { (300, 480) } else { (640, 480) };
        assert_eq!((c.w, c.h), size, "view {v}");
        assert!(registered(c), "view {v}: {c:?} {:?}", r.warnings);
        for kind in ["depth", "ids", "instances", "labels"] {
            let img = image::open(out.join(format!("{kind}/{v:03}.png"))).unwrap();
            assert_eq!((img.width(), img.height()), size, "{kind} {v}");
        }
    }
}

/// With `--photo-aspect` the network runs on 4:3 photos' own 128×96 grid: the model-resolution
/// maps of the preview are a quarter shorter than on the square, every view still registers,
/// and the depth and ids still come back at the photos' size.
#[test]
fn photos_run_on_a_grid_of_their_own_aspect_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let photos: Vec<PathBuf> = ["image_0000.pgm", "image_0004.pgm", "image_0008.pgm"]
        .iter()
        .map(|f| {
            let path = dir.path().join(Path::new(f).with_extension("png"));
            image::open(photos_dir().join("castel").join(f)).unwrap().save(&path).unwrap();
            path
        })
        .collect();
    let preview = |out: &Path| image::image_dimensions(out.join("preview.png")).unwrap();
    let square = dir.path().join("square");
    reconstruct(&photos, &square);
    let out = dir.path().join("aspect");
    let r = reconstruct_with(&photos, &out, &["--photo-aspect"]);
    let ((sw, sh), (aw, ah)) = (preview(&square), preview(&out));
    assert!(aw == sw && ah < sh, "preview {aw}×{ah} against the square's {sw}×{sh}");
    for (v, c) in r.cameras.iter().enumerate() {
        assert!(registered(c), "view {v}: {c:?} {:?}", r.warnings);
        for kind in ["depth", "ids"] {
            let img = image::open(out.join(format!("{kind}/{v:03}.png"))).unwrap();
            assert_eq!((img.width(), img.height()), (640, 480), "{kind} {v}");
        }
    }
}

#[test]
fn the_aloe_pairs_cameras_step_sideways() {
    let dir = tempfile::tempdir().unwrap();
    let pair: Vec<PathBuf> = ["aloeL.jpg", "aloeR.jpg"]
        .iter()
        .map(|f| with_exif(&photos_dir().join("aloe").join(f), dir.path(), ALOE_35MM))
        .collect();
    let out = dir.path().join("out");
    let r = reconstruct(&pair, &out);
    // Its truth is 8-bit disparity without the offset that would make it a depth: the
    // direction alone is checked.
    let off = sideways_off(&r);
    assert!(off < 10.0, "the baseline is {off:.1}° off the true sideways one");
    // Another pair's truth is refused by name, with both sizes.
    let truth = photos_dir().join("truth/motorcycle_disp.npz");
    let run = inssplat_eval(&["stereo", s(&out), "--disparity", s(&truth)]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && err.contains("motorcycle_disp.npz"), "{err}");
    assert!(err.contains("741×500") && err.contains("1282×1110"), "{err}");
}

#[test]
fn a_real_stereo_pair_takes_its_exif_focal_length_and_gives_masks_at_its_size() {
    let dir = tempfile::tempdir().unwrap();
    let photos = photos_dir();
    let pair: Vec<PathBuf> = ["motorcycle_left.png", "motorcycle_right.png"]
        .iter()
        .map(|f| with_exif(&photos.join("motorcycle").join(f), dir.path(), MOTORCYCLE_35MM))
        .collect();
    let out = dir.path().join("out");
    let r = reconstruct(&pair, &out);
    // 48 / 43.27 of the 894 px diagonal: 991.7 px, where the pair's calibration says 995.
    for c in &r.cameras {
        assert_eq!(c.focal, Some(FocalSource::Exif), "{c:?}");
        assert!((c.fl_x - 991.7).abs() < 1.0 && c.fl_x == c.fl_y, "{c:?}");
        assert_eq!((c.w, c.h), (741, 500));
    }
    // The right photo's camera lies to the right of the left one's: the matches' rays, not the
    // network's depth, tell the sideways step from a turn (0.0° measured). The depth, against
    // the true disparity (Middlebury 2014's doffs 124.343 px at 2964 px, here a quarter):
    // AbsRel 0.204 measured.
    let (off, abs_rel) = stereo_score(&out, &photos.join("truth/motorcycle_disp.npz"), 31.086);
    assert!(off < 5.0 && (off - sideways_off(&r)).abs() < 1e-3, "{off:.1}° off");
    assert!(abs_rel < 0.25, "depth AbsRel {abs_rel:.3}");
    // Masks, labels and ids at the photo's size, and the ids are the instance table's.
    for v in 0..2 {
        for kind in ["instances", "labels", "ids"] {
            let img = image::open(out.join(format!("{kind}/{v:03}.png"))).unwrap();
            assert_eq!((img.width(), img.height()), (741, 500), "{kind} {v}");
        }
    }
    let ids = image::open(out.join("ids/000.png")).unwrap().into_luma16();
    let found: std::collections::BTreeSet<u32> = ids.pixels().map(|p| u32::from(p[0])).collect();
    assert!(found.len() > 3, "{found:?}");
    assert!(found.iter().all(|&id| id == 0 || r.instances.iter().any(|i| i.id == id)));
    // The folder holds the photos as sent (their bytes, EXIF and all), named relative to it.
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap())
            .unwrap();
    for (v, photo) in pair.iter().enumerate() {
        let name = t["frames"][v]["file_path"].as_str().unwrap();
        assert_eq!(name, format!("images/{v:03}.jpg"));
        assert_eq!(std::fs::read(out.join(name)).unwrap(), std::fs::read(photo).unwrap());
    }
    // A query's masks come from those ids, at the photo's size.
    let best = r.instances.iter().max_by(|a, b| a.score.total_cmp(&b.score)).unwrap();
    let label = &best.label;
    let q = inssplat(&["query", s(&out), label, "--json"]);
    assert!(q.status.success(), "{}", String::from_utf8_lossy(&q.stderr));
    let answer: QueryResponse = serde_json::from_slice(&q.stdout).unwrap();
    let hit = answer.matches.iter().find(|m| m.instance_id == best.id).expect("its own label");
    let mask = &hit.masks[0];
    assert_eq!((mask.rle.width, mask.rle.height), (741, 500));
}

/// `inssplat detect --json` on `photos`: each photo's `[(class, score)]`, strongest first.
fn detect(photos: &[&Path]) -> Vec<Vec<(String, f64)>> {
    let mut args = vec!["detect", "--json"];
    args.extend(photos.iter().map(|p| s(p)));
    let run = inssplat(&args);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let found: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let list = found.as_array().unwrap();
    assert_eq!(list.len(), photos.len());
    list.iter()
        .map(|p| {
            let d = p["detections"].as_array().unwrap();
            d.iter().map(|d| (d["class"].as_str().unwrap().into(), d["score"].as_f64().unwrap()))
        })
        .map(Iterator::collect)
        .collect()
}

#[test]
fn the_detector_finds_the_motorcycle_and_nothing_in_a_blank_or_tiny_photo() {
    let dir = tempfile::tempdir().unwrap();
    let blank = dir.path().join("blank.png");
    RgbImage::from_pixel(64, 48, image::Rgb([128, 128, 128])).save(&blank).unwrap();
    let tiny = dir.path().join("tiny.png");
    RgbImage::from_fn(3, 2, |x, y| image::Rgb([40 * x as u8, 90 * y as u8, 200]))
        .save(&tiny)
        .unwrap();
    let motorcycle = photos_dir().join("motorcycle/motorcycle_left.png");
    let found = detect(&[&motorcycle, &blank, &tiny]);
    assert_eq!(found[0][0].0, "motorcycle", "{:?}", found[0]);
    assert!(found[0][0].1 > 0.7, "{:?}", found[0]);
    assert!(found[1].is_empty() && found[2].is_empty(), "{found:?}");
    // A file that is no photo: the error names it.
    let fake = dir.path().join("fake.png");
    std::fs::write(&fake, b"not a photo").unwrap();
    let run = inssplat(&["detect", s(&fake)]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("fake.png"));
}

#[test]
fn a_detected_class_names_the_nearest_word_and_a_street_is_not_forced_into_a_room() {
    let dir = tempfile::tempdir().unwrap();
    let pair: Vec<PathBuf> = ["motorcycle_left.png", "motorcycle_right.png"]
        .iter()
        .map(|n| photos_dir().join("motorcycle").join(n))
        .collect();
    // COCO's `motorcycle` is no word of this vocabulary; `motorbike` is the nearest.
    let out = dir.path().join("moto");
    let vocab = ["--vocab", "motorbike,wall,floor,chair,table"];
    let r = reconstruct_with(&pair, &out, &vocab);
    let by_detector: Vec<_> =
        r.instances.iter().filter(|i| i.named_by == NamedBy::Detector).collect();
    assert!(!by_detector.is_empty(), "{:?}", r.instances);
    for i in &by_detector {
        assert_eq!(i.label, "motorbike");
        assert_eq!(i.detector.as_ref().unwrap().class, "motorcycle");
    }
    let q = inssplat(&["query", s(&out), "the motorbike", "--json"]);
    assert!(q.status.success(), "{}", String::from_utf8_lossy(&q.stderr));
    let answer: QueryResponse = serde_json::from_slice(&q.stdout).unwrap();
    assert!(answer.matches.iter().any(|m| by_detector.iter().any(|i| i.id == m.instance_id)));
    // Without the detector, nothing is named so.
    let without = reconstruct_with(
        &pair,
        &dir.path().join("plain"),
        &[&vocab[..], &["--no-detector"]].concat(),
    );
    assert!(
        without.instances.iter().all(|i| i.named_by != NamedBy::Detector && i.detector.is_none())
    );

    // The street photos: the detector sees trucks, trains and people, none near a word of the
    // default vocabulary, so none names an instance.
    let street: Vec<PathBuf> =
        (2889..=2892).map(|n| photos_dir().join(format!("street/resized_IMG_{n}.jpg"))).collect();
    let r = reconstruct(&street, &dir.path().join("street"));
    assert!(r.instances.iter().any(|i| i.detector.is_some()), "the detector saw something");
    assert!(r.instances.iter().all(|i| i.named_by != NamedBy::Detector), "{:?}", r.instances);
}
