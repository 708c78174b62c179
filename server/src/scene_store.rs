//! Where the service keeps reconstructions: one folder per scene id under the data
//! directory, laid out as `inssplat reconstruct` writes it (so `saved::Saved` reads it back).
//! A scene is written into a staging folder and renamed into place, so a reader or a crash
//! never sees half a scene. Each read touches the scene's `.used` marker; the store keeps the
//! folders under a byte quota by removing the least recently used ones, and removes scenes
//! unused for longer than the expiry.

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use anyhow::Context;

/// A scene id: 32 lower-case hex digits (a UUID without dashes). Parsing is the only way to
/// make one from outside, so an id can never name a path outside the store.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct SceneId(String);

impl SceneId {
    /// A fresh random id.
    pub fn new() -> Self {
        Self(uuid::Uuid::new_v4().simple().to_string())
    }
}

impl Default for SceneId {
    fn default() -> Self {
        Self::new()
    }
}

/// Whether `s` is 32 lower-case hex digits (the form of scene and job ids).
pub fn is_id(s: &str) -> bool {
    s.len() == 32 && s.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

impl std::str::FromStr for SceneId {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        if is_id(s) {
            Ok(Self(s.to_string()))
        } else {
            Err(format!("`{}` is not a scene id (32 lower-case hex digits)", s.escape_debug()))
        }
    }
}

impl std::fmt::Display for SceneId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// Marker file whose modification time is the scene's last use.
const USED: &str = ".used";
/// Prefix of staging folders (never a valid id, so never served).
const STAGING: &str = ".staging-";

/// The scene folders and their limits.
#[derive(Debug, Clone)]
pub struct SceneStore {
    root: PathBuf,
    quota_bytes: u64,
    /// `None`: scenes never expire.
    expiry: Option<Duration>,
}

impl SceneStore {
    /// Opens (creating) `root` and removes staging folders a crash left behind.
    pub fn open(root: &Path, quota_bytes: u64, expiry: Option<Duration>) -> anyhow::Result<Self> {
        std::fs::create_dir_all(root)
            .with_context(|| format!("cannot create the scene folder {}", root.display()))?;
        for entry in std::fs::read_dir(root)
            .with_context(|| format!("cannot list {}", root.display()))?
            .flatten()
        {
            if entry.file_name().to_string_lossy().starts_with(STAGING) {
                std::fs::remove_dir_all(entry.path())
                    .with_context(|| format!("cannot remove {}", entry.path().display()))?;
            }
        }
        Ok(Self { root: root.to_path_buf(), quota_bytes, expiry })
    }

    /// An empty staging folder for `id`, to write the scene into before [`SceneStore::commit`].
    pub fn staging(&self, id: &SceneId) -> anyhow::Result<PathBuf> {
        let dir = self.root.join(format!("{STAGING}{id}"));
        if dir.exists() {
            std::fs::remove_dir_all(&dir)
                .with_context(|| format!("cannot clear {}", dir.display()))?;
        }
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        Ok(dir)
    }

    /// Moves the staged scene `id` into place (replacing an older copy), then evicts other
    /// scenes as the quota and expiry require.
    pub fn commit(&self, id: &SceneId) -> anyhow::Result<()> {
        let staged = self.root.join(format!("{STAGING}{id}"));
        std::fs::write(staged.join(USED), b"")
            .with_context(|| format!("cannot write {}", staged.join(USED).display()))?;
        let dir = self.root.join(id.to_string());
        if dir.exists() {
            std::fs::remove_dir_all(&dir)
                .with_context(|| format!("cannot replace {}", dir.display()))?;
        }
        std::fs::rename(&staged, &dir)
            .with_context(|| format!("cannot move {} to {}", staged.display(), dir.display()))?;
        self.evict(Some(id))?;
        Ok(())
    }

    /// The folder of scene `id` if it is stored, marking it used.
    pub fn open_scene(&self, id: &SceneId) -> Option<PathBuf> {
        let dir = self.root.join(id.to_string());
        let marker = std::fs::OpenOptions::new().write(true).open(dir.join(USED)).ok()?;
        // A failed touch only makes the scene look older to the eviction.
        let _ = marker.set_modified(SystemTime::now());
        Some(dir)
    }

    /// Bytes held by stored scenes.
    pub fn total_bytes(&self) -> u64 {
        self.scenes().iter().map(|s| s.bytes).sum()
    }

    /// Removes expired scenes, then the least recently used until the rest fit the quota;
    /// `keep` is never removed. Returns how many scenes were removed.
    pub fn evict(&self, keep: Option<&SceneId>) -> anyhow::Result<usize> {
        let mut scenes = self.scenes();
        scenes.sort_by_key(|s| s.used);
        let now = SystemTime::now();
        let mut total: u64 = scenes.iter().map(|s| s.bytes).sum();
        let mut removed = 0;
        for s in &scenes {
            if keep.is_some_and(|k| k.0 == s.id) {
                continue;
            }
            let expired =
                self.expiry.is_some_and(|e| now.duration_since(s.used).unwrap_or_default() > e);
            if expired || total > self.quota_bytes {
                let dir = self.root.join(&s.id);
                std::fs::remove_dir_all(&dir)
                    .with_context(|| format!("cannot remove {}", dir.display()))?;
                total -= s.bytes;
                removed += 1;
            }
        }
        Ok(removed)
    }

    fn scenes(&self) -> Vec<StoredScene> {
        let Ok(entries) = std::fs::read_dir(&self.root) else { return Vec::new() };
        entries
            .flatten()
            .filter_map(|e| {
                let id = e.file_name().to_string_lossy().into_owned();
                if !is_id(&id) {
                    return None;
                }
                let used = std::fs::metadata(e.path().join(USED))
                    .and_then(|m| m.modified())
                    .unwrap_or(SystemTime::UNIX_EPOCH);
                Some(StoredScene { bytes: folder_bytes(&e.path()), id, used })
            })
            .collect()
    }
}

struct StoredScene {
    id: String,
    used: SystemTime,
    bytes: u64,
}

/// Bytes of the files under `dir`.
fn folder_bytes(dir: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    entries
        .flatten()
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => folder_bytes(&e.path()),
            _ => e.metadata().map_or(0, |m| m.len()),
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn store_scene(store: &SceneStore, bytes: usize) -> SceneId {
        let id = SceneId::new();
        let dir = store.staging(&id).unwrap();
        std::fs::write(dir.join("scene.ply"), vec![0u8; bytes]).unwrap();
        store.commit(&id).unwrap();
        id
    }

    #[test]
    fn ids_refuse_anything_but_32_hex_digits() {
        assert!("0123456789abcdef0123456789abcdef".parse::<SceneId>().is_ok());
        for bad in [
            "",
            "..",
            "../../etc/passwd",
            "0123456789ABCDEF0123456789ABCDEF",
            "0123456789abcdef0123456789abcde/",
        ] {
            assert!(bad.parse::<SceneId>().is_err(), "{bad}");
        }
    }

    #[test]
    fn evicts_least_recently_used_over_quota_and_never_the_new_one() {
        let dir = tempfile::tempdir().unwrap();
        let store = SceneStore::open(dir.path(), 2500, None).unwrap();
        let a = store_scene(&store, 1000);
        std::thread::sleep(Duration::from_millis(20));
        let b = store_scene(&store, 1000);
        std::thread::sleep(Duration::from_millis(20));
        assert!(store.open_scene(&a).is_some(), "a is now the most recently used");
        let c = store_scene(&store, 1000);
        assert!(store.open_scene(&b).is_none(), "b was least recently used");
        assert!(store.open_scene(&a).is_some() && store.open_scene(&c).is_some());
        let big = store_scene(&store, 5000);
        assert!(store.open_scene(&big).is_some(), "a scene over the whole quota is still kept");
        assert!(store.total_bytes() >= 5000);
    }

    #[test]
    fn expired_scenes_and_crash_leftovers_go() {
        let dir = tempfile::tempdir().unwrap();
        let store =
            SceneStore::open(dir.path(), u64::MAX, Some(Duration::from_millis(10))).unwrap();
        let old = store_scene(&store, 10);
        let half = SceneId::new();
        store.staging(&half).unwrap();
        std::thread::sleep(Duration::from_millis(30));
        let new = store_scene(&store, 10);
        assert!(store.open_scene(&old).is_none() && store.open_scene(&new).is_some());
        SceneStore::open(dir.path(), u64::MAX, None).unwrap();
        assert!(!dir.path().join(format!("{STAGING}{half}")).exists());
    }
}
