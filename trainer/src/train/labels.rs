//! The semantic teacher's label embeddings: MiniLM itself (`INSSPLAT_TEXT_MODEL`), or a saved
//! table of the embeddings of every label the synthesizer can produce
//! (`INSSPLAT_LABEL_TABLE`, written by `inssplat-train label-table`), so a training machine
//! can carry a few hundred kilobytes instead of the 90 MB weights. Both give the same vectors.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use inssplat_text::{EMBEDDING_DIM, Embedding, LabelCache, TextEmbedder};
use serde::{Deserialize, Serialize};

use super::TrainError;
use inssplat_synth as synth;

/// Environment variable naming a label table to use instead of the text model.
pub const LABEL_TABLE_ENV: &str = "INSSPLAT_LABEL_TABLE";

/// The file written by [`write_label_table`].
#[derive(Serialize, Deserialize)]
struct LabelTable {
    /// The model folder the embeddings came from.
    model: String,
    labels: BTreeMap<String, Vec<f32>>,
}

/// The label cache the semantic teacher reads: from the table named by `INSSPLAT_LABEL_TABLE`
/// when set, else MiniLM.
pub fn label_cache() -> Result<Arc<LabelCache>, TrainError> {
    match std::env::var_os(LABEL_TABLE_ENV) {
        Some(path) => read_label_table(Path::new(&path)).map(Arc::new),
        None => Ok(Arc::new(LabelCache::new(TextEmbedder::from_env()?))),
    }
}

/// Embeds every label of [`synth::all_labels`] with MiniLM and writes them to `path`; returns
/// how many.
pub fn write_label_table(path: &Path) -> Result<usize, TrainError> {
    let cache = LabelCache::new(TextEmbedder::from_env()?);
    let labels: Vec<&str> = synth::all_labels().into_iter().collect();
    cache.embed(&labels)?;
    let model = cache.embedder()?.model_dir().display().to_string();
    let table = LabelTable {
        model,
        labels: cache.entries().into_iter().map(|(l, e)| (l, e.to_vec())).collect(),
    };
    let text = serde_json::to_string(&table).map_err(|e| super::io_error(path, e))?;
    std::fs::write(path, text).map_err(|e| super::io_error(path, e))?;
    Ok(labels.len())
}

fn read_label_table(path: &Path) -> Result<LabelCache, TrainError> {
    let bad = |problem: String| super::io_error(path, format!("{LABEL_TABLE_ENV}: {problem}"));
    let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
    let table: LabelTable =
        serde_json::from_str(&text).map_err(|e| bad(format!("not a label table: {e}")))?;
    let entries = table.labels.into_iter().map(|(label, v)| {
        let embedding: Embedding = v.as_slice().try_into().map_err(|_| {
            bad(format!("label {label:?} has {} numbers, not {EMBEDDING_DIM}", v.len()))
        })?;
        Ok((label, embedding))
    });
    Ok(LabelCache::from_table(entries.collect::<Result<Vec<_>, TrainError>>()?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_table_reads_back_with_the_models_vectors_and_a_bad_one_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("labels.json");
        assert_eq!(write_label_table(&path).unwrap(), synth::all_labels().len());
        let table = read_label_table(&path).unwrap();
        let model = LabelCache::new(TextEmbedder::from_env().unwrap());
        assert_eq!(
            table.embed(&["chair", "wall"]).unwrap(),
            model.embed(&["chair", "wall"]).unwrap()
        );
        std::fs::write(&path, "{\"model\": \"m\", \"labels\": {\"chair\": [1.0]}}").unwrap();
        let err = read_label_table(&path).unwrap_err().to_string();
        assert!(
            err.contains("labels.json")
                && err.contains(LABEL_TABLE_ENV)
                && err.contains("\"chair\" has 1 numbers"),
            "{err}"
        );
    }
}
