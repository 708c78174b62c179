//! Where the service keeps reconstructions: one folder per scene id under the data
//! directory, laid out as `inssplat reconstruct` writes it (so `saved::Saved` reads it back).
//! A scene is written into a staging folder and renamed into place, so a reader or a crash
//! never sees half a scene. Each read touches the scene's `.used` marker; the store keeps the
//! folders under a byte quota by removing the least recently used ones, and removes scenes
//! unused for longer than the expiry.
//!
//! Replicas may share the folder (one volume, one PostgreSQL job store): everything is in the
//! files, none of it in memory. Each replica stages under its own name in `.staging/`, and
//! commits, reads and evictions only rename and remove whole folders, so replicas doing them
//! at once at worst both remove the same scene.

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
/// The folder of the replicas' staging folders (never a valid id, so never served).
const STAGING: &str = ".staging";
/// Age after which another replica's staged scene is a crash's leftover: no scene takes this
/// long, and a replica's claim on a job scene runs out far sooner.
const ABANDONED: Duration = Duration::from_secs(3600);

/// The scene folders and their limits.
#[derive(Debug, Clone)]
pub struct SceneStore {
    root: PathBuf,
    /// This replica's staging folder.
    staging: PathBuf,
    quota_bytes: u64,
    /// `None`: scenes never expire.
    expiry: Option<Duration>,
}

/// A scene being written: fill [`Staged::dir`], then [`SceneStore::commit`] it.
#[derive(Debug)]
pub struct Staged {
    id: SceneId,
    dir: PathBuf,
}

impl Staged {
    /// The folder to write the scene into.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl SceneStore {
    /// Opens (creating) `root` for `replica` (a name no other replica sharing `root` has),
    /// removing what this replica staged before a crash and what others staged over an hour
    /// ago.
    pub fn open(
        root: &Path,
        replica: &str,
        quota_bytes: u64,
        expiry: Option<Duration>,
    ) -> anyhow::Result<Self> {
        let folder: String = replica
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() || c == '.' || c == '-' { c } else { '_' })
            .collect();
        let staging = root.join(STAGING).join(folder);
        remove_gone(&staging)?;
        std::fs::create_dir_all(&staging)
            .with_context(|| format!("cannot create the scene folder {}", staging.display()))?;
        let others = std::fs::read_dir(root.join(STAGING))
            .with_context(|| format!("cannot list {}", root.join(STAGING).display()))?;
        for replica in others.flatten().filter(|e| e.path() != staging) {
            for staged in std::fs::read_dir(replica.path()).into_iter().flatten().flatten() {
                let age = staged.metadata().and_then(|m| m.modified()).map(|t| t.elapsed());
                if matches!(age, Ok(Ok(age)) if age > ABANDONED) {
                    remove_gone(&staged.path())?;
                }
            }
        }
        Ok(Self { root: root.to_path_buf(), staging, quota_bytes, expiry })
    }

    /// An empty staging folder for scene `id` (a new one each call, so two attempts at one
    /// scene never write into one folder).
    pub fn staging(&self, id: &SceneId) -> anyhow::Result<Staged> {
        let dir = self.staging.join(format!("{id}-{}", SceneId::new()));
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        Ok(Staged { id: id.clone(), dir })
    }

    /// Moves the staged scene into place (replacing an older copy), then evicts other scenes
    /// as the quota and expiry require.
    pub fn commit(&self, staged: Staged) -> anyhow::Result<()> {
        let Staged { id, dir: staged } = staged;
        std::fs::write(staged.join(USED), b"")
            .with_context(|| format!("cannot write {}", staged.join(USED).display()))?;
        let dir = self.root.join(id.to_string());
        // An older copy is renamed aside (atomic, like the move in) and removed; another try
        // covers another replica committing the same scene in between.
        for attempt in 0.. {
            match std::fs::rename(&staged, &dir) {
                Ok(()) => break,
                Err(_) if attempt < 2 && dir.exists() => {
                    let old = self.staging.join(format!("{id}-replaced-{}", SceneId::new()));
                    match std::fs::rename(&dir, &old) {
                        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                            return Err(e)
                                .with_context(|| format!("cannot replace {}", dir.display()));
                        }
                        _ => remove_gone(&old)?,
                    }
                }
                Err(e) => {
                    return Err(e).with_context(|| {
                        format!("cannot move {} to {}", staged.display(), dir.display())
                    });
                }
            }
        }
        self.evict(Some(&id))?;
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
                remove_gone(&self.root.join(&s.id))?;
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

/// Removes the folder `dir`; one already gone (another replica removed it) is no error.
fn remove_gone(dir: &Path) -> anyhow::Result<()> {
    match std::fs::remove_dir_all(dir) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(e).with_context(|| format!("cannot remove {}", dir.display()))
        }
        _ => Ok(()),
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
        let staged = store.staging(&id).unwrap();
        std::fs::write(staged.dir().join("scene.ply"), vec![0u8; bytes]).unwrap();
        store.commit(staged).unwrap();
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
        let store = SceneStore::open(dir.path(), "a", 2500, None).unwrap();
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
            SceneStore::open(dir.path(), "a", u64::MAX, Some(Duration::from_millis(10))).unwrap();
        let old = store_scene(&store, 10);
        let half = store.staging(&SceneId::new()).unwrap();
        std::thread::sleep(Duration::from_millis(30));
        let new = store_scene(&store, 10);
        assert!(store.open_scene(&old).is_none() && store.open_scene(&new).is_some());
        SceneStore::open(dir.path(), "b", u64::MAX, None).unwrap();
        assert!(half.dir().exists(), "another replica's fresh staging stays");
        SceneStore::open(dir.path(), "a", u64::MAX, None).unwrap();
        assert!(!half.dir().exists(), "the replica's own leftovers go when it starts again");
    }

    #[test]
    fn replicas_sharing_the_folder_commit_the_same_scene_and_read_each_others() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (
            SceneStore::open(dir.path(), "host:127.0.0.1:8080", u64::MAX, None).unwrap(),
            SceneStore::open(dir.path(), "host:127.0.0.1:8081", u64::MAX, None).unwrap(),
        );
        let id = SceneId::new();
        // Both run the scene (a claim that lapsed); both commit, in either order.
        let (from_a, from_b) = (a.staging(&id).unwrap(), b.staging(&id).unwrap());
        assert_ne!(from_a.dir(), from_b.dir());
        std::fs::write(from_a.dir().join("scene.ply"), b"a").unwrap();
        std::fs::write(from_b.dir().join("scene.ply"), b"b").unwrap();
        b.commit(from_b).unwrap();
        a.commit(from_a).unwrap();
        let read = b.open_scene(&id).expect("b reads what a committed");
        assert_eq!(std::fs::read(read.join("scene.ply")).unwrap(), b"a");
        // Both evict the same scene: the second finds it gone, which is no error.
        let (tight_a, tight_b) = (
            SceneStore::open(dir.path(), "host:127.0.0.1:8080", 0, None).unwrap(),
            SceneStore::open(dir.path(), "host:127.0.0.1:8081", 0, None).unwrap(),
        );
        assert_eq!(tight_a.evict(None).unwrap(), 1);
        assert_eq!(tight_b.evict(None).unwrap(), 0);
        assert!(a.open_scene(&id).is_none());
    }
}
