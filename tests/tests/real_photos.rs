//! A user's own photos through the real binary with the shipped network: the Middlebury
//! motorcycle stereo pair (741×500, from the scikit-image wheel that `scripts/setup` unpacks),
//! saved as a phone would, JPEG with the 35 mm-equivalent focal length in its EXIF. The
//! cameras take that focal length and the baseline's direction, the masks come back at the
//! photos' resolution, and the output folder holds the photos its `transforms.json` names.

use std::path::{Path, PathBuf};

use crate::support::photo::save_jpeg_with_exif;
use crate::support::s;
use inssplat_e2e::inssplat;
use inssplat_proto::api::{FocalSource, QueryResponse, ReconstructResponse};

/// The pair's focal length, 995 px (Middlebury 2014's calibration, scaled to 741 px), as the
/// 35 mm-equivalent EXIF field gives it: whole millimetres.
const FOCAL_35MM: u16 = 48;

/// `photo` as a JPEG in `dir` whose EXIF says a `FOCAL_35MM` mm-equivalent lens took it.
fn with_exif(photo: &Path, dir: &Path) -> PathBuf {
    let rgb = image::open(photo).unwrap().to_rgb8();
    let path = dir.join(photo.with_extension("jpg").file_name().unwrap());
    let focal = (exif::Tag::FocalLengthIn35mmFilm, exif::Value::Short(vec![FOCAL_35MM]));
    save_jpeg_with_exif(&rgb, &[focal], &path);
    path
}

#[test]
fn a_real_stereo_pair_takes_its_exif_focal_length_and_gives_masks_at_its_size() {
    let dir = tempfile::tempdir().unwrap();
    let photos = std::env::var_os("INSSPLAT_PHOTOS_DIR")
        .map(PathBuf::from)
        .expect("INSSPLAT_PHOTOS_DIR (set by `source .deps/env` after scripts/setup)");
    let pair: Vec<PathBuf> = ["motorcycle_left.png", "motorcycle_right.png"]
        .iter()
        .map(|f| with_exif(&photos.join(f), dir.path()))
        .collect();
    let out = dir.path().join("out");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx");
    let run = inssplat(&[
        "reconstruct",
        s(&pair[0]),
        s(&pair[1]),
        "-o",
        s(&out),
        "--model",
        s(&model),
        "--json",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let r: ReconstructResponse = serde_json::from_slice(&run.stdout).unwrap();
    // 48 / 43.27 of the 894 px diagonal: 991.7 px, where the pair's calibration says 995.
    for c in &r.cameras {
        assert_eq!(c.focal, Some(FocalSource::Exif), "{c:?}");
        assert!((c.fl_x - 991.7).abs() < 1.0 && c.fl_x == c.fl_y, "{c:?}");
        assert_eq!((c.w, c.h), (741, 500));
    }
    // The right photo's camera lies to the right of the left one's (nerfstudio axes: x right):
    // the matches' rays, not the network's depth, tell the sideways step from a turn.
    let m = &r.cameras[1].transform_matrix;
    let step = glam::DVec3::new(m[0][3], m[1][3], m[2][3]);
    let off = step.normalize().dot(glam::DVec3::X).acos().to_degrees();
    assert!(off < 25.0, "the baseline is {off:.1}° off the true sideways one: {step:?}");
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
