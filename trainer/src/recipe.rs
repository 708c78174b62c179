//! A training run given as a TOML file (`inssplat-train train --config RUN.toml`). Each key is
//! a flag of `train` without its leading dashes, spelled with dashes or underscores
//! (`lr = 1.5e-4`, `camera-rays = 2`, `semantic-objects-only = true`); a list is given with
//! commas. The file's flags are placed before the command line's, and a flag given in both
//! takes the command line's value, so a recipe can be rerun with one flag changed.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// A recipe that cannot be read, naming the file and the key at fault.
#[derive(Debug, thiserror::Error)]
pub enum RecipeError {
    #[error("--config {path}: {message}")]
    Read { path: PathBuf, message: String },
    #[error("--config {path}: key `{key}`: {problem}")]
    Key { path: PathBuf, key: String, problem: String },
    #[error("--config needs a file name")]
    MissingPath,
}

/// The flags of the recipe at `path`, by key in alphabetical order (the order of flags does not
/// matter: each is given once).
pub fn flags(path: &Path) -> Result<Vec<String>, RecipeError> {
    let read = |message: String| RecipeError::Read { path: path.to_path_buf(), message };
    let text = std::fs::read_to_string(path).map_err(|e| read(e.to_string()))?;
    let table: toml::Table = text.parse().map_err(|e: toml::de::Error| read(e.to_string()))?;
    let mut out = Vec::new();
    for (key, value) in &table {
        let bad = |problem: &str| RecipeError::Key {
            path: path.to_path_buf(),
            key: key.clone(),
            problem: problem.to_string(),
        };
        if matches!(key.as_str(), "config" | "out" | "resume") {
            return Err(bad(
                "give the run folder and --resume on the command line, not in a recipe",
            ));
        }
        let flag = format!("--{}", key.replace('_', "-"));
        let scalar = |v: &toml::Value| match v {
            toml::Value::String(s) => Ok(s.clone()),
            toml::Value::Integer(i) => Ok(i.to_string()),
            toml::Value::Float(f) => Ok(f.to_string()),
            _ => Err(bad("expected a string, a number, true/false or a list of them")),
        };
        match value {
            toml::Value::Boolean(true) => out.push(flag),
            toml::Value::Boolean(false) => {}
            toml::Value::Array(items) => {
                let items = items.iter().map(scalar).collect::<Result<Vec<_>, _>>()?;
                out.push(format!("{flag}={}", items.join(",")));
            }
            other => out.push(format!("{flag}={}", scalar(other)?)),
        }
    }
    Ok(out)
}

/// `args` (a whole command line, program name first) with the flags of `train --config FILE`'s
/// recipe inserted right after `train`; other command lines are returned as given.
pub fn expand(args: Vec<OsString>) -> Result<Vec<OsString>, RecipeError> {
    if args.get(1).is_none_or(|a| a != "train") {
        return Ok(args);
    }
    let mut path = None;
    for (i, arg) in args.iter().enumerate() {
        match arg.to_str() {
            Some("--config") => {
                path = Some(PathBuf::from(args.get(i + 1).ok_or(RecipeError::MissingPath)?))
            }
            Some(a) if a.starts_with("--config=") => {
                path = Some(PathBuf::from(&a["--config=".len()..]))
            }
            _ => {}
        }
    }
    let Some(path) = path else { return Ok(args) };
    let recipe = flags(&path)?;
    let mut out: Vec<OsString> = args[..2].to_vec();
    out.extend(recipe.into_iter().map(OsString::from));
    out.extend_from_slice(&args[2..]);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn os(args: &[&str]) -> Vec<OsString> {
        args.iter().map(OsString::from).collect()
    }

    #[test]
    fn a_recipe_becomes_flags_before_the_command_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.toml");
        std::fs::write(&path, "lr = 1.5e-4\ncamera_rays = 2\nsemantic-objects-only = true\nno-boundary = false\nsome-list = [1, 8]\n").unwrap();
        let args = expand(os(&[
            "t",
            "train",
            "--out",
            "r",
            "--config",
            path.to_str().unwrap(),
            "--lr",
            "3e-4",
        ]))
        .unwrap();
        let recipe =
            ["--camera-rays=2", "--lr=0.00015", "--semantic-objects-only", "--some-list=1,8"];
        let given = ["--out", "r", "--config", path.to_str().unwrap(), "--lr", "3e-4"];
        let want = os(&[&["t", "train"][..], &recipe, &given].concat());
        assert_eq!(args, want);
        let other = os(&["t", "export", "--config", "x"]);
        assert_eq!(expand(other.clone()).unwrap(), other, "only train reads recipes");
    }

    #[test]
    fn a_bad_recipe_names_the_file_and_the_key() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.toml");
        std::fs::write(&path, "lr = { peak = 1 }\n").unwrap();
        let err = flags(&path).unwrap_err().to_string();
        assert!(err.contains("bad.toml") && err.contains("`lr`"), "{err}");
        std::fs::write(&path, "out = \"runs/x\"\n").unwrap();
        let err = flags(&path).unwrap_err().to_string();
        assert!(err.contains("`out`") && err.contains("command line"), "{err}");
        std::fs::write(&path, "lr = \n").unwrap();
        assert!(flags(&path).unwrap_err().to_string().contains("bad.toml"));
        let missing = flags(&dir.path().join("none.toml")).unwrap_err().to_string();
        assert!(missing.contains("none.toml"), "{missing}");
    }
}
