use super::*;
use crate::gaussian::{Gaussian, SceneMeta};

/// A deterministic pseudo-random scene (xorshift), so tests need no RNG crate.
fn scene(n: usize, sem_dim: usize) -> GaussianScene {
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut r = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
    };
    let mut s = GaussianScene::with_sem_dim(sem_dim);
    s.meta = SceneMeta {
        producer: "inssplat-test".into(),
        model_version: Some("m1".into()),
        up_axis: Some("-y".into()),
        labels: vec![(1, "office chair".into()), (2, "lamp".into())],
    };
    for i in 0..n {
        let sem: Vec<f32> = (0..sem_dim).map(|_| r()).collect();
        s.push(Gaussian {
            mean: [r(), r(), r()],
            log_scale: [r(), r(), r()],
            rotation: [r(), r(), r(), r()],
            logit_opacity: r(),
            sh_dc: [r(), r(), r()],
            confidence: r(),
            instance_embedding: std::array::from_fn(|_| r()),
            semantic: &sem,
            instance_id: (i % 3) as u32,
        });
    }
    s
}

fn to_bytes(s: &GaussianScene) -> Vec<u8> {
    let mut out = Vec::new();
    write_ply(&mut out, s).unwrap();
    out
}

fn header_text(bytes: &[u8]) -> String {
    let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    String::from_utf8(bytes[..end].to_vec()).unwrap()
}

#[test]
fn header_lists_standard_properties_first_then_extras() {
    let text = header_text(&to_bytes(&scene(3, 2)));
    let props: Vec<&str> = text.lines().filter_map(|l| l.strip_prefix("property ")).collect();
    let standard: Vec<String> = STANDARD_PROPERTIES.iter().map(|p| format!("float {p}")).collect();
    assert_eq!(props[..17], standard.iter().map(String::as_str).collect::<Vec<_>>()[..]);
    assert_eq!(
        props[17..],
        [
            "float confidence",
            "uint instance_id",
            "float ins_0",
            "float ins_1",
            "float ins_2",
            "float ins_3",
            "float ins_4",
            "float ins_5",
            "float ins_6",
            "float ins_7",
            "float sem_0",
            "float sem_1"
        ]
    );
    assert!(text.starts_with("ply\nformat binary_little_endian 1.0\n"), "{text}");
    assert!(text.contains("element vertex 3\n"));
    assert!(text.contains("comment label 1 office chair\n"));
}

#[test]
fn round_trip_is_bit_identical() {
    let s = scene(257, 5);
    let bytes = to_bytes(&s);
    let back = read_ply(&mut bytes.as_slice()).unwrap();
    assert_eq!(back, s);
    assert_eq!(to_bytes(&back), bytes, "re-written file is byte-identical");
}

#[test]
fn empty_scene_round_trips() {
    let s = scene(0, 3);
    let back = read_ply(&mut to_bytes(&s).as_slice()).unwrap();
    assert_eq!(back.len(), 0);
    assert_eq!(back.sem_dim, 3);
}

/// A file as written by the INRIA 3DGS code: normals, 45 f_rest, no extras.
fn inria_file(n: usize) -> Vec<u8> {
    let mut text = format!("ply\nformat binary_little_endian 1.0\nelement vertex {n}\n");
    let mut names: Vec<String> =
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"].map(String::from).to_vec();
    names.extend((0..45).map(|i| format!("f_rest_{i}")));
    names.extend(
        ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
            .map(String::from),
    );
    for p in &names {
        text.push_str(&format!("property float {p}\n"));
    }
    text.push_str("end_header\n");
    let mut bytes = text.into_bytes();
    for i in 0..n {
        for (k, _) in names.iter().enumerate() {
            bytes.extend_from_slice(&((i * 100 + k) as f32).to_le_bytes());
        }
    }
    bytes
}

#[test]
fn reads_a_plain_3dgs_file_without_extras() {
    let s = read_ply(&mut inria_file(4).as_slice()).unwrap();
    assert_eq!(s.len(), 4);
    assert_eq!(s.means[2], [200.0, 201.0, 202.0]);
    assert_eq!(s.sh_dc[1], [106.0, 107.0, 108.0]);
    assert_eq!(s.logit_opacity[0], 54.0, "opacity follows the 45 f_rest values");
    assert_eq!(s.rotations[3], [358.0, 359.0, 360.0, 361.0]);
    assert_eq!((s.sem_dim, s.instance_id[0], s.confidence[0]), (0, 0, 1.0));
}

#[test]
fn reads_an_ascii_file() {
    let text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n\
        property float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\nproperty float opacity\n\
        property float scale_0\nproperty float scale_1\nproperty float scale_2\nproperty float rot_0\n\
        property float rot_1\nproperty float rot_2\nproperty float rot_3\nproperty uchar instance_id\nend_header\n\
        1 2 3 0.1 0.2 0.3 -1 -2 -3 -4 1 0 0 0 7\n";
    let s = read_ply(&mut text.as_bytes()).unwrap();
    assert_eq!(s.means[0], [1.0, 2.0, 3.0]);
    assert_eq!(s.instance_id[0], 7);
}

#[test]
fn truncated_file_names_element_record_and_property() {
    let bytes = to_bytes(&scene(10, 2));
    let header_len = header_text(&bytes).len();
    let record = 4 * (17 + 2 + 8 + 2);
    // Cut in record 6, inside the 11th float (scale_0 starts at byte 40).
    let cut = header_len + 6 * record + 41;
    let err = read_ply(&mut &bytes[..cut]).unwrap_err();
    match &err {
        PlyError::Truncated { element, index, count, property } => {
            assert_eq!(
                (element.as_str(), *index, *count, property.as_str()),
                ("vertex", 6, 10, "scale_0")
            );
        }
        other => panic!("expected Truncated, got {other:?}"),
    }
    assert!(err.to_string().contains("`vertex`") && err.to_string().contains("`scale_0`"), "{err}");
}

#[test]
fn missing_required_property_is_named() {
    let text = "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\nend_header\n";
    let err = read_ply(&mut text.as_bytes()).unwrap_err();
    assert!(matches!(err, PlyError::MissingProperty { property: "z", .. }), "{err:?}");
}

#[test]
fn list_typed_required_property_is_rejected() {
    let mut text =
        String::from("ply\nformat ascii 1.0\nelement vertex 0\nproperty list uchar float x\n");
    for p in REQUIRED.iter().skip(1) {
        text.push_str(&format!("property float {p}\n"));
    }
    text.push_str("end_header\n");
    let err = read_ply(&mut text.as_bytes()).unwrap_err();
    assert!(matches!(&err, PlyError::BadType { property, .. } if property == "x"), "{err:?}");
}

#[test]
fn malformed_header_and_missing_vertex_are_errors() {
    assert!(matches!(read_ply(&mut &b"not a ply file\n"[..]), Err(PlyError::Header(_))));
    let no_vertex = "ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
    assert!(matches!(read_ply(&mut no_vertex.as_bytes()), Err(PlyError::MissingElement("vertex"))));
}

#[test]
fn ascii_payload_garbage_names_the_element() {
    let text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n\
        property float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\nproperty float opacity\n\
        property float scale_0\nproperty float scale_1\nproperty float scale_2\nproperty float rot_0\n\
        property float rot_1\nproperty float rot_2\nproperty float rot_3\nend_header\n1 2 three\n";
    let err = read_ply(&mut text.as_bytes()).unwrap_err();
    assert!(matches!(&err, PlyError::Payload { element, .. } if element == "vertex"), "{err:?}");
}
