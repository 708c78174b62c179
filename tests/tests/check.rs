//! `inssplat check` on real scene folders written by `proto`.

use glam::Vec3;
use inssplat_e2e::inssplat;
use inssplat_proto::dataset::{Frame, InstanceLabel, Scene};
use inssplat_proto::{Camera, Intrinsics};

fn scene() -> Scene {
    let k = Intrinsics::from_fov_y(8, 8, 1.0);
    let frames = (0..3)
        .map(|i| Frame {
            camera: Camera::look_at(k, Vec3::new(i as f32, 1.0, -2.0), Vec3::ZERO, Vec3::Y),
            rgb: vec![100; 192],
            depth: Some(vec![2.0; 64]),
            instances: Some((0..64).map(|p| (p % 2) as u16).collect()),
        })
        .collect();
    Scene {
        dir: Default::default(),
        instances: vec![InstanceLabel { id: 1, label: "chair".into() }],
        frames,
        eval: None,
        depth_unit_m: 0.001,
    }
}

#[test]
fn check_accepts_a_valid_scene_and_reports_it_as_json() {
    let dir = tempfile::tempdir().unwrap();
    scene().write(dir.path()).unwrap();
    let out = inssplat(&["check", "--json", dir.path().to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("\"frames\":3") && text.contains("\"labels\":[\"chair\"]"), "{text}");
}

#[test]
fn check_names_the_file_and_field_of_a_broken_scene() {
    let dir = tempfile::tempdir().unwrap();
    scene().write(dir.path()).unwrap();
    std::fs::remove_file(dir.path().join("depth/002.png")).unwrap();
    let out = inssplat(&["check", dir.path().to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("depth/002.png") && err.contains("frames[2].depth_file_path"), "{err}");
}
