//! A job's uploads on disk: named photo sets, or a tar or zip archive of scene folders, are
//! written under the job's input folder, one folder per scene, in the form `inputs::photo_paths`
//! reads (a folder of photos, or a dataset scene with its `transforms.json`). Archive entries
//! are checked before anything is written: only plain relative paths (no `..`, no absolute
//! paths, no links), and a cap on the bytes unpacked, so an archive cannot write outside the
//! folder or fill the disk.

use std::io::{Cursor, Read};
use std::path::{Component, Path, PathBuf};

use inssplat_proto::signature::{MAX_VIEWS, MIN_VIEWS};

/// At most this many scenes in one job.
pub const MAX_SCENES: usize = 256;
/// At most this many entries in one archive.
const MAX_ENTRIES: usize = 100_000;

/// Why an upload cannot become a job; the message names the scene or entry at fault.
#[derive(Debug, thiserror::Error)]
pub enum IntakeError {
    #[error("{0}")]
    Invalid(String),
    #[error("storing the upload: {0}")]
    Io(#[from] std::io::Error),
}

fn invalid(msg: impl Into<String>) -> IntakeError {
    IntakeError::Invalid(msg.into())
}

/// One uploaded photo.
pub struct Photo {
    pub file_name: String,
    pub bytes: Vec<u8>,
}

/// Whether a scene name (a multipart field name) is usable: 1–64 of `A-Za-z0-9_.-`, not
/// starting with a dot.
pub fn valid_scene_name(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && !name.starts_with('.')
        && name.bytes().all(|b| b.is_ascii_alphanumeric() || b"_.-".contains(&b))
}

/// The part of an uploaded file name kept on disk (so errors still name the photo): up to 40
/// of `A-Za-z0-9_-` from its stem.
fn file_stem(name: &str) -> String {
    let stem =
        Path::new(name).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    stem.chars().filter(|c| c.is_ascii_alphanumeric() || "_-".contains(*c)).take(40).collect()
}

/// Writes each named photo set to `dest/NNN/` (photos renamed `NNN_<stem>.<format>`, in
/// upload order) and returns the scenes (name, folder).
pub fn write_photo_sets(
    sets: Vec<(String, Vec<Photo>)>,
    dest: &Path,
) -> Result<Vec<(String, PathBuf)>, IntakeError> {
    if sets.is_empty() {
        return Err(invalid(
            "the job has no scenes: send photo sets (a file field per photo, named by its scene) or an `archive`",
        ));
    }
    if sets.len() > MAX_SCENES {
        return Err(invalid(format!("{} scenes in one job; at most {MAX_SCENES}", sets.len())));
    }
    for (name, photos) in &sets {
        if !(MIN_VIEWS..=MAX_VIEWS).contains(&photos.len()) {
            return Err(invalid(format!(
                "scene `{name}`: {} photos; a scene needs {MIN_VIEWS} to {MAX_VIEWS}",
                photos.len()
            )));
        }
    }
    let mut scenes = Vec::new();
    for (s, (name, photos)) in sets.into_iter().enumerate() {
        let dir = dest.join(format!("{s:03}"));
        std::fs::create_dir_all(&dir)?;
        for (i, photo) in photos.into_iter().enumerate() {
            let ext = image::guess_format(&photo.bytes)
                .ok()
                .and_then(|f| f.extensions_str().first().copied())
                .filter(|e| ["png", "jpg", "webp"].contains(e))
                .ok_or_else(|| {
                    invalid(format!(
                        "scene `{name}`: {}: not a PNG, JPEG or WebP image",
                        photo.file_name
                    ))
                })?;
            std::fs::write(
                dir.join(format!("{i:03}_{}.{ext}", file_stem(&photo.file_name))),
                &photo.bytes,
            )?;
        }
        scenes.push((name, dir));
    }
    Ok(scenes)
}

/// The archive formats a job can arrive in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArchiveKind {
    Tar,
    Zip,
}

impl ArchiveKind {
    /// Recognizes an archive from its first bytes.
    pub fn sniff(bytes: &[u8]) -> Option<Self> {
        if bytes.starts_with(b"PK\x03\x04") {
            Some(Self::Zip)
        } else if bytes.get(257..262) == Some(b"ustar") {
            Some(Self::Tar)
        } else {
            None
        }
    }
}

/// A relative path made of plain components only, or an error naming the entry.
fn safe_path(entry: &str) -> Result<PathBuf, IntakeError> {
    let path = Path::new(entry);
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::Normal(part) => out.push(part),
            Component::CurDir => {}
            _ => {
                return Err(invalid(format!(
                    "archive entry `{}`: only relative paths inside the archive are allowed",
                    entry.escape_debug()
                )));
            }
        }
    }
    Ok(out)
}

/// Unpacks `bytes` into `dest` (at most `max_bytes` of file content) and returns its scenes:
/// every folder that holds a `transforms.json` or photos directly, named by its path in the
/// archive, in path order.
pub fn unpack_archive(
    bytes: &[u8],
    kind: ArchiveKind,
    dest: &Path,
    max_bytes: u64,
) -> Result<Vec<(String, PathBuf)>, IntakeError> {
    let mut budget = max_bytes;
    let mut write = |name: &str, size: u64, reader: &mut dyn Read| -> Result<(), IntakeError> {
        let rel = safe_path(name)?;
        if size > budget {
            return Err(invalid(format!(
                "the archive unpacks to more than {max_bytes} bytes (at `{}`)",
                name.escape_debug()
            )));
        }
        budget -= size;
        let path = dest.join(&rel);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)?;
        }
        let mut file = std::fs::File::create(&path)?;
        let copied = std::io::copy(&mut reader.take(size), &mut file)?;
        if copied != size {
            return Err(invalid(format!("archive entry `{}` is truncated", name.escape_debug())));
        }
        Ok(())
    };
    let mut entries = 0usize;
    let mut count = || {
        entries += 1;
        if entries > MAX_ENTRIES {
            Err(invalid(format!("the archive has more than {MAX_ENTRIES} entries")))
        } else {
            Ok(())
        }
    };
    match kind {
        ArchiveKind::Tar => {
            let mut archive = tar::Archive::new(Cursor::new(bytes));
            for entry in archive
                .entries()
                .map_err(|e| invalid(format!("not a readable tar archive: {e}")))?
            {
                count()?;
                let mut entry = entry.map_err(|e| invalid(format!("corrupt tar archive: {e}")))?;
                let name = entry
                    .path()
                    .map_err(|e| invalid(format!("corrupt tar entry name: {e}")))?
                    .to_string_lossy()
                    .into_owned();
                match entry.header().entry_type() {
                    tar::EntryType::Directory => {
                        std::fs::create_dir_all(dest.join(safe_path(&name)?))?;
                    }
                    tar::EntryType::Regular | tar::EntryType::Continuous => {
                        let size = entry
                            .header()
                            .size()
                            .map_err(|e| invalid(format!("tar entry `{name}`: {e}")))?;
                        write(&name, size, &mut entry)?;
                    }
                    tar::EntryType::XGlobalHeader | tar::EntryType::XHeader => {}
                    other => {
                        return Err(invalid(format!(
                            "archive entry `{}`: {other:?} entries are not allowed",
                            name.escape_debug()
                        )));
                    }
                }
            }
        }
        ArchiveKind::Zip => {
            let mut archive = zip::ZipArchive::new(Cursor::new(bytes))
                .map_err(|e| invalid(format!("not a readable zip archive: {e}")))?;
            for i in 0..archive.len() {
                count()?;
                let mut file = archive
                    .by_index(i)
                    .map_err(|e| invalid(format!("corrupt zip entry {i}: {e}")))?;
                let name = file
                    .name()
                    .map_err(|e| invalid(format!("zip entry {i}: unreadable name: {e}")))?
                    .into_owned();
                if file.is_symlink() {
                    return Err(invalid(format!(
                        "archive entry `{}`: links are not allowed",
                        name.escape_debug()
                    )));
                }
                if file.is_dir() {
                    std::fs::create_dir_all(dest.join(safe_path(&name)?))?;
                } else {
                    let size = file.size();
                    write(&name, size, &mut file)?;
                }
            }
        }
    }
    let mut scenes = Vec::new();
    find_scenes(dest, dest, &mut scenes)?;
    scenes.sort();
    if scenes.is_empty() {
        return Err(invalid(
            "the archive holds no scene: no folder with a transforms.json or with .png/.jpg/.webp photos",
        ));
    }
    if scenes.len() > MAX_SCENES {
        return Err(invalid(format!(
            "the archive holds {} scenes; at most {MAX_SCENES}",
            scenes.len()
        )));
    }
    Ok(scenes)
}

/// Folders under `dir` that are scenes (a dataset scene's own sub-folders are not).
fn find_scenes(root: &Path, dir: &Path, out: &mut Vec<(String, PathBuf)>) -> std::io::Result<()> {
    let mut children = Vec::new();
    let mut has_photos = false;
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let path = entry.path();
        if entry.file_type()?.is_dir() {
            children.push(path);
        } else if path.extension().is_some_and(|e| {
            ["png", "jpg", "jpeg", "webp"].iter().any(|x| e.eq_ignore_ascii_case(x))
        }) {
            has_photos = true;
        }
    }
    let name = || {
        let rel = dir.strip_prefix(root).unwrap_or(dir).to_string_lossy().into_owned();
        if rel.is_empty() { ".".to_string() } else { rel }
    };
    if dir.join("transforms.json").is_file() {
        out.push((name(), dir.to_path_buf()));
        return Ok(());
    }
    if has_photos {
        out.push((name(), dir.to_path_buf()));
    }
    for child in children {
        find_scenes(root, &child, out)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tar_with(entries: &[(&str, &[u8])]) -> Vec<u8> {
        let mut b = tar::Builder::new(Vec::new());
        for (name, data) in entries {
            let mut h = tar::Header::new_gnu();
            h.set_size(data.len() as u64);
            h.set_mode(0o644);
            h.set_entry_type(tar::EntryType::Regular);
            // set_path refuses `..`; write the raw name to test what a hostile archive can hold.
            h.as_old_mut().name[..name.len()].copy_from_slice(name.as_bytes());
            h.set_cksum();
            b.append(&h, *data).unwrap();
        }
        b.into_inner().unwrap()
    }

    #[test]
    fn finds_photo_folders_and_dataset_scenes() {
        let dir = tempfile::tempdir().unwrap();
        let bytes = tar_with(&[
            ("a/1.png", b"x"),
            ("a/2.png", b"y"),
            ("b/transforms.json", b"{}"),
            ("b/images/000.png", b"z"),
        ]);
        assert_eq!(ArchiveKind::sniff(&bytes), Some(ArchiveKind::Tar));
        let scenes = unpack_archive(&bytes, ArchiveKind::Tar, dir.path(), 1000).unwrap();
        let names: Vec<&str> = scenes.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["a", "b"]);
    }

    #[test]
    fn refuses_traversal_and_oversized_archives() {
        let dir = tempfile::tempdir().unwrap();
        let evil = tar_with(&[("../evil.png", b"x")]);
        let err =
            unpack_archive(&evil, ArchiveKind::Tar, &dir.path().join("in"), 1000).unwrap_err();
        assert!(err.to_string().contains("../evil.png"), "{err}");
        assert!(!dir.path().join("evil.png").exists());
        let big = tar_with(&[("a/1.png", &[0u8; 600]), ("a/2.png", &[0u8; 600])]);
        let err =
            unpack_archive(&big, ArchiveKind::Tar, &dir.path().join("in2"), 1000).unwrap_err();
        assert!(err.to_string().contains("more than 1000 bytes"), "{err}");
        assert!(safe_path("/etc/passwd").is_err() && safe_path("a/./b.png").is_ok());
    }

    #[test]
    fn photo_sets_need_2_to_16_real_images() {
        let dir = tempfile::tempdir().unwrap();
        let png = inssplat_pipeline::output::png_bytes(&image::RgbImage::new(2, 2));
        let photo = |b: &[u8]| Photo { file_name: "p.png".into(), bytes: b.to_vec() };
        let err =
            write_photo_sets(vec![("one".into(), vec![photo(&png)])], dir.path()).unwrap_err();
        assert!(err.to_string().contains("scene `one`: 1 photos"), "{err}");
        let err =
            write_photo_sets(vec![("x".into(), vec![photo(&png), photo(b"text")])], dir.path())
                .unwrap_err();
        assert!(err.to_string().contains("not a PNG"), "{err}");
        let ok = write_photo_sets(vec![("x".into(), vec![photo(&png), photo(&png)])], dir.path())
            .unwrap();
        assert!(ok[0].1.join("001_p.png").is_file());
        assert_eq!(file_stem("../../x y.png"), "xy");
        assert!(
            valid_scene_name("kitchen-2") && !valid_scene_name("../x") && !valid_scene_name("")
        );
    }
}
