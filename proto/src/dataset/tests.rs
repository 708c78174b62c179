use std::path::{Path, PathBuf};

use glam::{Quat, Vec3};
use proptest::prelude::*;
use serde_json::{Value, json};

use super::*;
use crate::camera::{CameraError, Intrinsics};

/// A small valid scene: two 6×4 frames with depth and instances 1 and 2.
fn sample() -> Scene {
    let k = Intrinsics { fx: 5.0, fy: 5.0, cx: 3.0, cy: 2.0, width: 6, height: 4 };
    let frames = (0..2)
        .map(|i| Frame {
            camera: Camera::look_at(k, Vec3::new(i as f32, 1.0, -3.0), Vec3::ZERO, Vec3::Y),
            rgb: (0..72).map(|v| (v * 3 + i) as u8).collect(),
            depth: Some(
                (0..24).map(|v| ((1000 + v * 7) as f64 * DEFAULT_DEPTH_UNIT_M) as f32).collect(),
            ),
            instances: Some((0..24).map(|v| (v % 3) as u16).collect()),
        })
        .collect();
    Scene {
        dir: PathBuf::new(),
        instances: vec![
            InstanceLabel { id: 1, label: "chair".into() },
            InstanceLabel { id: 2, label: "lamp".into() },
        ],
        frames,
        eval: None,
        depth_unit_m: DEFAULT_DEPTH_UNIT_M,
    }
}

fn written() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    sample().write(dir.path()).unwrap();
    dir
}

fn edit_json(dir: &Path, f: impl FnOnce(&mut Value)) {
    let path = dir.join("transforms.json");
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(path, serde_json::to_string(&v).unwrap()).unwrap();
}

/// Loads `dir`, expects a rejection naming `file` (suffix) and `field` (prefix).
fn rejected(dir: &Path, file: &str, field: &str) -> Problem {
    let err = Scene::load(dir).expect_err("scene should be rejected");
    assert!(err.file.ends_with(file), "file {:?} should end with {file}: {err}", err.file);
    assert!(err.field.starts_with(field), "field {:?} should start with {field}: {err}", err.field);
    let text = err.to_string();
    assert!(
        text.contains(file) && text.contains(&err.field),
        "message names file and field: {text}"
    );
    err.problem
}

#[test]
fn valid_scene_round_trips() {
    let dir = written();
    let back = Scene::load(dir.path()).unwrap();
    let orig = sample();
    assert_eq!(back.instances, orig.instances);
    for (a, b) in back.frames.iter().zip(&orig.frames) {
        assert_eq!((&a.rgb, &a.depth, &a.instances), (&b.rgb, &b.depth, &b.instances));
        assert!((a.camera.center() - b.camera.center()).length() < 1e-5);
    }
    assert_eq!(back.label_vocabulary(), ["chair", "lamp"]);
    assert_eq!(back.label_of(2), Some("lamp"));
}

#[test]
fn rejects_missing_transforms() {
    let dir = tempfile::tempdir().unwrap();
    assert!(matches!(rejected(dir.path(), "transforms.json", "(file)"), Problem::Missing));
}

#[test]
fn rejects_missing_image() {
    let dir = written();
    std::fs::remove_file(dir.path().join("images/001.png")).unwrap();
    assert!(matches!(
        rejected(dir.path(), "images/001.png", "frames[1].file_path"),
        Problem::Missing
    ));
}

#[test]
fn rejects_unreadable_image() {
    let dir = written();
    std::fs::write(dir.path().join("images/000.png"), b"\x89PNG\r\n\x1a\nnot really").unwrap();
    assert!(matches!(
        rejected(dir.path(), "images/000.png", "frames[0].file_path"),
        Problem::Unreadable(_)
    ));
}

#[test]
fn rejects_zero_byte_image() {
    let dir = written();
    std::fs::write(dir.path().join("images/000.png"), b"").unwrap();
    assert!(matches!(
        rejected(dir.path(), "images/000.png", "frames[0].file_path"),
        Problem::Unreadable(_)
    ));
}

#[test]
fn rejects_image_size_that_differs_from_intrinsics() {
    let dir = written();
    edit_json(dir.path(), |v| v["w"] = json!(7));
    assert!(matches!(
        rejected(dir.path(), "images/000.png", "frames[0].file_path"),
        Problem::SizeMismatch { .. }
    ));
}

#[test]
fn rejects_depth_of_another_size() {
    let dir = written();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(5, 4, vec![1000u16; 20])
        .unwrap()
        .save(dir.path().join("depth/001.png"))
        .unwrap();
    let p = rejected(dir.path(), "depth/001.png", "frames[1].depth_file_path");
    assert!(matches!(p, Problem::SizeMismatch { found_w: 5, expected_w: 6, .. }), "{p}");
}

#[test]
fn reads_a_smaller_depth_of_the_photos_shape_at_the_photos_size() {
    let dir = written();
    // Half the 6×4 frame: each pixel stands for the 2×2 it covers.
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(3, 2, vec![1, 2, 3, 4, 5, 6])
        .unwrap()
        .save(dir.path().join("depth/001.png"))
        .unwrap();
    let scene = Scene::load(dir.path()).unwrap();
    let depth = scene.frames[1].depth.as_ref().unwrap();
    let steps: Vec<u32> =
        depth.iter().map(|d| (f64::from(*d) / DEFAULT_DEPTH_UNIT_M).round() as u32).collect();
    assert_eq!(steps, [1, 1, 2, 2, 3, 3, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 4, 4, 5, 5, 6, 6]);
}

#[test]
fn rejects_instance_mask_of_another_size() {
    let dir = written();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(6, 3, vec![0u16; 18])
        .unwrap()
        .save(dir.path().join("instances/000.png"))
        .unwrap();
    let p = rejected(dir.path(), "instances/000.png", "frames[0].instance_file_path");
    assert!(matches!(p, Problem::SizeMismatch { found_h: 3, expected_h: 4, .. }), "{p}");
}

#[test]
fn rejects_8_bit_depth() {
    let dir = written();
    image::GrayImage::from_raw(6, 4, vec![9u8; 24])
        .unwrap()
        .save(dir.path().join("depth/000.png"))
        .unwrap();
    assert!(matches!(
        rejected(dir.path(), "depth/000.png", "frames[0].depth_file_path"),
        Problem::PixelFormat { .. }
    ));
}

#[test]
fn rejects_non_finite_transform() {
    // JSON has no NaN literal; an overflowing number is how a non-finite value arrives.
    let dir = written();
    edit_json(dir.path(), |v| v["frames"][1]["transform_matrix"][0][3] = json!(12345.5));
    let path = dir.path().join("transforms.json");
    let text = std::fs::read_to_string(&path).unwrap().replace("12345.5", "1e999");
    std::fs::write(&path, text).unwrap();
    let p = rejected(dir.path(), "transforms.json", "frames[1].transform_matrix");
    assert!(matches!(p, Problem::Json(_)), "{p}");
}

#[test]
fn rejects_singular_transform() {
    let dir = written();
    edit_json(dir.path(), |v| {
        v["frames"][1]["transform_matrix"] =
            json!([[1, 0, 0, 0], [2, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    });
    let p = rejected(dir.path(), "transforms.json", "frames[1].transform_matrix");
    assert!(matches!(p, Problem::Transform(CameraError::Singular(_))), "{p}");
}

#[test]
fn rejects_non_affine_transform() {
    let dir = written();
    edit_json(dir.path(), |v| v["frames"][0]["transform_matrix"][3] = json!([0, 0, 0, 2]));
    let p = rejected(dir.path(), "transforms.json", "frames[0].transform_matrix");
    assert!(matches!(p, Problem::Transform(CameraError::NotAffine(_))), "{p}");
}

#[test]
fn rejects_unknown_instance_id() {
    let dir = written();
    edit_json(dir.path(), |v| v["instances"] = json!([{"id": 1, "label": "chair"}]));
    let p = rejected(dir.path(), "instances/000.png", "frames[0].instance_file_path");
    assert!(matches!(p, Problem::UnknownInstance { id: 2, x: 2, y: 0 }), "{p}");
}

#[test]
fn rejects_parent_dir_path() {
    let dir = written();
    edit_json(dir.path(), |v| v["frames"][0]["file_path"] = json!("../outside.png"));
    assert!(matches!(
        rejected(dir.path(), "transforms.json", "frames[0].file_path"),
        Problem::PathEscapes(_)
    ));
}

#[test]
fn rejects_absolute_path() {
    let dir = written();
    edit_json(dir.path(), |v| v["frames"][1]["depth_file_path"] = json!("/etc/passwd"));
    assert!(matches!(
        rejected(dir.path(), "transforms.json", "frames[1].depth_file_path"),
        Problem::PathEscapes(_)
    ));
}

#[test]
fn rejects_bad_json() {
    let dir = written();
    std::fs::write(dir.path().join("transforms.json"), "{\"frames\": [").unwrap();
    assert!(matches!(rejected(dir.path(), "transforms.json", ""), Problem::Json(_)));
}

#[test]
fn rejects_wrong_types() {
    let dir = written();
    edit_json(dir.path(), |v| v["frames"][1]["file_path"] = json!(3));
    assert!(matches!(
        rejected(dir.path(), "transforms.json", "frames[1].file_path"),
        Problem::Json(_)
    ));
    // The intrinsics too, at either level: the error names the field, not its object.
    let dir = written();
    edit_json(dir.path(), |v| v["frames"][1]["fl_y"] = json!("x"));
    assert!(matches!(rejected(dir.path(), "transforms.json", "frames[1].fl_y"), Problem::Json(_)));
    let dir = written();
    edit_json(dir.path(), |v| v["cx"] = json!([]));
    assert!(matches!(rejected(dir.path(), "transforms.json", "cx"), Problem::Json(_)));
}

#[test]
fn rejects_empty_frames() {
    let dir = written();
    edit_json(dir.path(), |v| v["frames"] = json!([]));
    assert!(matches!(rejected(dir.path(), "transforms.json", "frames"), Problem::Invalid(_)));
}

#[test]
fn frame_intrinsics_override_the_top_level_and_integers_read_as_floats() {
    let dir = written();
    edit_json(dir.path(), |v| {
        v["fl_x"] = json!(7);
        v["frames"][1]["fl_y"] = json!(9);
    });
    let back = Scene::load(dir.path()).unwrap();
    let k = |i: usize| back.frames[i].camera.intrinsics;
    assert_eq!((k(0).fx, k(0).fy, k(1).fx, k(1).fy), (7.0, 5.0, 7.0, 9.0));
    assert_eq!((k(1).cx, k(1).width), (3.0, 6));
}

#[test]
fn rejects_missing_intrinsics() {
    let dir = written();
    edit_json(dir.path(), |v| v.as_object_mut().unwrap().remove("fl_x").map(drop).unwrap_or(()));
    assert!(matches!(
        rejected(dir.path(), "transforms.json", "frames[0].fl_x"),
        Problem::Invalid(_)
    ));
}

#[test]
fn rejects_duplicate_instance_id() {
    let dir = written();
    edit_json(dir.path(), |v| {
        v["instances"] = json!([{"id": 1, "label": "a"}, {"id": 1, "label": "b"}])
    });
    assert!(matches!(
        rejected(dir.path(), "transforms.json", "instances[1].id"),
        Problem::Invalid(_)
    ));
}

#[test]
fn rejects_eval_frames_out_of_range_or_overlapping() {
    let dir = written();
    edit_json(dir.path(), |v| v["eval"] = json!({"context": {"2": [0, 1]}, "target": [5]}));
    rejected(dir.path(), "transforms.json", "eval.target[0]");
    edit_json(dir.path(), |v| v["eval"] = json!({"context": {"2": [0, 1]}, "target": [1]}));
    rejected(dir.path(), "transforms.json", "eval.context.2");
}

fn arb_scene() -> impl Strategy<Value = Scene> {
    let frame = (
        1u32..6,
        1u32..5,
        prop::array::uniform4(-1.0f32..1.0),
        prop::array::uniform3(-5.0f32..5.0),
        any::<bool>(),
        any::<u64>(),
    );
    (prop::collection::vec(frame, 1..4), 0usize..4).prop_map(|(frames, n_inst)| {
        let (w, h) = (frames[0].0, frames[0].1);
        let instances = (1..=n_inst as u32)
            .map(|id| InstanceLabel { id: id * 7, label: format!("thing {id}") })
            .collect::<Vec<_>>();
        let frames = frames
            .into_iter()
            .enumerate()
            .map(|(i, (_, _, q, t, gt, seed))| {
                let k = Intrinsics {
                    fx: 3.0 + i as f32,
                    fy: 3.5,
                    cx: w as f32 / 2.0,
                    cy: h as f32 / 2.0,
                    width: w,
                    height: h,
                };
                let q = Quat::from_xyzw(q[1], q[2], q[3], q[0]);
                let rotation =
                    if q.is_finite() && q.length() > 1e-3 { q.normalize() } else { Quat::IDENTITY };
                let n = (w * h) as usize;
                let mix = |j: usize| {
                    seed.wrapping_mul(6364136223846793005)
                        .wrapping_add((j as u64).wrapping_mul(1442695040888963407))
                        >> 33
                };
                Frame {
                    camera: Camera { intrinsics: k, rotation, translation: Vec3::from(t) },
                    rgb: (0..3 * n).map(|j| mix(j) as u8).collect(),
                    depth: gt.then(|| {
                        (0..n)
                            .map(|j| ((mix(j) % 60000) as f64 * DEFAULT_DEPTH_UNIT_M) as f32)
                            .collect()
                    }),
                    instances: (gt && n_inst > 0).then(|| {
                        (0..n).map(|j| ((mix(j) % (n_inst as u64 + 1)) * 7) as u16).collect()
                    }),
                }
            })
            .collect();
        Scene {
            dir: PathBuf::new(),
            instances,
            frames,
            eval: None,
            depth_unit_m: DEFAULT_DEPTH_UNIT_M,
        }
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn writer_reader_round_trip(scene in arb_scene()) {
        let dir = tempfile::tempdir().unwrap();
        scene.write(dir.path()).unwrap();
        let back = Scene::load(dir.path()).unwrap();
        prop_assert_eq!(&back.instances, &scene.instances);
        prop_assert_eq!(back.frames.len(), scene.frames.len());
        for (a, b) in back.frames.iter().zip(&scene.frames) {
            prop_assert_eq!(&a.rgb, &b.rgb);
            prop_assert_eq!(&a.depth, &b.depth);
            prop_assert_eq!(&a.instances, &b.instances);
            prop_assert_eq!(a.camera.intrinsics, b.camera.intrinsics);
            prop_assert!(a.camera.rotation.dot(b.camera.rotation).abs() > 1.0 - 1e-5);
            prop_assert!((a.camera.translation - b.camera.translation).length() < 1e-4);
        }
        // Writing what was read gives the same bytes.
        let again = tempfile::tempdir().unwrap();
        back.write(again.path()).unwrap();
        let f = "images/000.png";
        prop_assert_eq!(std::fs::read(dir.path().join(f)).unwrap(), std::fs::read(again.path().join(f)).unwrap());
    }
}

#[test]
fn planar_rgb_puts_each_channel_in_its_own_plane_and_name_is_the_folder() {
    let mut scene = sample();
    scene.dir = PathBuf::from("/data/test/scene_000007");
    assert_eq!(scene.name(), "scene_000007");
    let frame = &mut scene.frames[0];
    frame.rgb = (0..frame.rgb.len()).map(|i| (i % 256) as u8).collect();
    let planar = frame.planar_rgb();
    let pixels = (frame.width() * frame.height()) as usize;
    assert_eq!(planar.len(), 3 * pixels);
    for p in [0, 1, pixels - 1] {
        for c in 0..3 {
            assert_eq!(planar[c * pixels + p], f32::from(frame.rgb[p * 3 + c]) / 255.0);
        }
    }
}
