//! The label vocabulary: the default list of indoor object names (the categories the
//! training scenes use, plus common neighbours), or one the user gives as a file (one label a
//! line) or a comma-separated list.

use std::path::Path;

use anyhow::Context;
use inssplat_text::{LabelCache, TextEmbedder};

/// Default labels: every category the training scenes use (catalog furniture and primitive
/// objects of `inssplat-train synth`, and the room shell: ceiling, floor, wall), so a user gets
/// the names the model was taught.
pub const DEFAULT_VOCABULARY: &[&str] = &[
    "armchair",
    "ball",
    "bathtub",
    "bed",
    "bench",
    "bookcase",
    "box",
    "cabinet",
    "ceiling",
    "chair",
    "coffee table",
    "computer",
    "desk",
    "dresser",
    "fan",
    "fireplace",
    "floor",
    "guitar",
    "lamp",
    "nightstand",
    "office chair",
    "oven",
    "piano",
    "picture",
    "plant",
    "pool table",
    "radiator",
    "refrigerator",
    "rug",
    "sink",
    "sofa",
    "speaker",
    "stool",
    "table",
    "toilet",
    "trash can",
    "tv",
    "tv stand",
    "vase",
    "wall",
    "wardrobe",
    "washing machine",
];

/// The text encoder of `INSSPLAT_TEXT_MODEL` (or the setup step's copy), behind its cache of
/// label embeddings.
pub fn label_cache() -> anyhow::Result<LabelCache> {
    Ok(LabelCache::new(TextEmbedder::from_env().context("loading the text encoder")?))
}

/// The vocabulary from `--vocab`: a readable file means one label per line, anything else a
/// comma-separated list; `None` gives the default.
pub fn vocabulary(arg: Option<&str>) -> anyhow::Result<Vec<String>> {
    let raw: Vec<String> = match arg {
        None => DEFAULT_VOCABULARY.iter().map(|s| s.to_string()).collect(),
        Some(a) if Path::new(a).is_file() => std::fs::read_to_string(a)
            .with_context(|| format!("cannot read vocabulary file {a}"))?
            .lines()
            .map(str::to_string)
            .collect(),
        Some(a) => a.split(',').map(str::to_string).collect(),
    };
    let v = normalize(raw);
    anyhow::ensure!(!v.is_empty(), "--vocab {}: no labels in it", arg.unwrap_or(""));
    Ok(v)
}

/// A vocabulary sent as text (over HTTP): labels separated by commas or new lines, never a
/// file name. Empty when the text names no label.
pub fn from_list(text: &str) -> Vec<String> {
    normalize(text.split([',', '\n']).map(str::to_string).collect())
}

/// Trimmed, non-empty, sorted, de-duplicated labels.
fn normalize(raw: Vec<String>) -> Vec<String> {
    let mut v: Vec<String> =
        raw.into_iter().map(|s| s.trim().to_string()).filter(|s| !s.is_empty()).collect();
    v.sort();
    v.dedup();
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_lists_files_and_rejects_empty() {
        assert_eq!(vocabulary(Some(" lamp, chair ,lamp")).unwrap(), ["chair", "lamp"]);
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("v.txt");
        std::fs::write(&f, "sofa\n\nbed\n").unwrap();
        assert_eq!(vocabulary(Some(f.to_str().unwrap())).unwrap(), ["bed", "sofa"]);
        assert!(vocabulary(Some(" , ")).is_err());
        assert!(vocabulary(None).unwrap().len() >= 20);
        assert_eq!(from_list("lamp\r\nsofa, lamp"), ["lamp", "sofa"]);
        assert!(from_list(" ,\n").is_empty());
    }
}
