//! Hostile bytes for the malformed-request test: PNG headers that lie about their size, and
//! tar archives, one of them reaching out of its folder.

use crate::support::http::png;

/// A PNG header claiming `w`×`h` (with a valid CRC), followed by nothing.
pub(super) fn png_header(w: u32, h: u32) -> Vec<u8> {
    let mut bytes = png(1, 1, 0);
    bytes[16..20].copy_from_slice(&w.to_be_bytes());
    bytes[20..24].copy_from_slice(&h.to_be_bytes());
    let crc = crc(&bytes[12..29]);
    bytes[29..33].copy_from_slice(&crc.to_be_bytes());
    bytes
}

fn crc(data: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in data {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 == 1 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

/// A tar archive (made by the system's `tar`) of `files` (path, bytes) under a temp folder.
pub(super) fn tar_of(files: &[(&str, &[u8])]) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    for (path, bytes) in files {
        let p = dir.path().join("root").join(path);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    }
    let out = dir.path().join("a.tar");
    let ok = std::process::Command::new("tar")
        .args(["-cf", out.to_str().unwrap(), "-C", dir.path().join("root").to_str().unwrap(), "."])
        .status()
        .unwrap();
    assert!(ok.success());
    std::fs::read(out).unwrap()
}

/// A tar whose only entry is named `../escape.png` (written by hand: tools refuse to).
pub(super) fn traversal_tar() -> Vec<u8> {
    let mut header = [0u8; 512];
    let name = b"../escape.png";
    header[..name.len()].copy_from_slice(name);
    header[100..108].copy_from_slice(b"0000644\0");
    header[108..116].copy_from_slice(b"0000000\0");
    header[116..124].copy_from_slice(b"0000000\0");
    header[124..136].copy_from_slice(b"00000000004\0");
    header[136..148].copy_from_slice(b"00000000000\0");
    header[156] = b'0';
    header[257..263].copy_from_slice(b"ustar\0");
    header[263..265].copy_from_slice(b"00");
    header[148..156].copy_from_slice(b"        ");
    let sum: u32 = header.iter().map(|&b| u32::from(b)).sum();
    header[148..156].copy_from_slice(format!("{sum:06o}\0 ").as_bytes());
    let mut out = header.to_vec();
    let mut data = [0u8; 512];
    data[..4].copy_from_slice(b"evil");
    out.extend_from_slice(&data);
    out.extend_from_slice(&[0u8; 1024]);
    out
}
