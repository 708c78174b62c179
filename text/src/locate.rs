//! Finding the model folder. `INSSPLAT_TEXT_MODEL` wins when it is set (scripts/setup writes
//! it to .deps/env); otherwise the setup step's default location `<workspace>/.deps/
//! all-minilm-l6-v2-<version>/` is looked for in the folders above the running executable and
//! above the current directory, newest version first. Nothing is ever downloaded: a folder
//! that is missing, or that lacks one of the model files, is a [`TextError::ModelNotFound`]
//! naming both the variable and the default location.

use std::path::{Path, PathBuf};

use crate::error::{Result, TextError};

/// Environment variable holding the model folder.
pub const MODEL_ENV: &str = "INSSPLAT_TEXT_MODEL";

/// Default model location, relative to the workspace root (the setup step installs it there).
pub const DEFAULT_MODEL_GLOB: &str = ".deps/all-minilm-l6-v2-*";

const DEPS_DIR: &str = ".deps";
const MODEL_DIR_PREFIX: &str = "all-minilm-l6-v2-";

/// Weights, in a folder that holds the model.
pub(crate) const WEIGHTS_FILE: &str = "model.safetensors";
/// Tokenizer, in a folder that holds the model.
pub(crate) const TOKENIZER_FILE: &str = "tokenizer.json";
/// BERT configuration, in a folder that holds the model.
pub(crate) const CONFIG_FILE: &str = "config.json";

/// The model folder, from `INSSPLAT_TEXT_MODEL` (when set and not empty) or else from the
/// default location above the executable or the current directory.
pub fn locate_model() -> Result<PathBuf> {
    let from_env = std::env::var_os(MODEL_ENV).filter(|v| !v.is_empty()).map(PathBuf::from);
    let mut roots = Vec::new();
    if let Some(exe_dir) =
        std::env::current_exe().ok().and_then(|e| e.parent().map(Path::to_path_buf))
    {
        roots.push(exe_dir);
    }
    if let Ok(cwd) = std::env::current_dir() {
        roots.push(cwd);
    }
    locate_model_in(from_env.as_deref(), &roots)
}

/// [`locate_model`] with its inputs spelled out: `from_env` is the value of
/// `INSSPLAT_TEXT_MODEL` (`None` when unset), `roots` the folders whose ancestors (themselves
/// included) may hold `.deps/all-minilm-l6-v2-*/`.
pub fn locate_model_in(from_env: Option<&Path>, roots: &[PathBuf]) -> Result<PathBuf> {
    if let Some(dir) = from_env {
        return match missing_file(dir) {
            None => Ok(dir.to_path_buf()),
            Some(why) => Err(TextError::ModelNotFound {
                searched: format!("{MODEL_ENV}={} but {why}", dir.display()),
            }),
        };
    }
    for root in roots {
        for folder in root.ancestors() {
            if let Some(found) = newest_model_dir(&folder.join(DEPS_DIR)) {
                return Ok(found);
            }
        }
    }
    let roots: Vec<String> = roots.iter().map(|r| r.display().to_string()).collect();
    Err(TextError::ModelNotFound {
        searched: format!(
            "{MODEL_ENV} is not set and no {DEFAULT_MODEL_GLOB}/ holding the model files is in \
             [{}] or any folder above them",
            roots.join(", ")
        ),
    })
}

/// `None` when `dir` holds every model file; otherwise what is missing, as words.
pub(crate) fn missing_file(dir: &Path) -> Option<String> {
    if !dir.is_dir() {
        return Some(format!("{} is not a folder", dir.display()));
    }
    [WEIGHTS_FILE, TOKENIZER_FILE, CONFIG_FILE]
        .iter()
        .find(|f| !dir.join(f).is_file())
        .map(|f| format!("{} has no {f}", dir.display()))
}

/// The complete `all-minilm-l6-v2-<version>` folder in `deps` with the highest version.
fn newest_model_dir(deps: &Path) -> Option<PathBuf> {
    std::fs::read_dir(deps)
        .ok()?
        .filter_map(|entry| entry.ok())
        .filter_map(|entry| {
            let name = entry.file_name().into_string().ok()?;
            let version = name.strip_prefix(MODEL_DIR_PREFIX)?;
            let key: Vec<u64> = version.split('.').map(|p| p.parse().unwrap_or(0)).collect();
            let path = entry.path();
            missing_file(&path).is_none().then_some((key, path))
        })
        .max()
        .map(|(_, path)| path)
}
