//! Per-process memo of label embeddings. The server names every scene's instances against the
//! same label vocabulary and the trainer's semantic teacher embeds the same category names
//! every step, so each distinct (trimmed) label is run through the network once and then
//! served from memory. Query text, which rarely repeats, goes to the embedder directly.
//! A cache can also be built from a saved table of label embeddings with no model loaded
//! (a training machine that carries the table instead of the 90 MB weights); it then knows
//! exactly the labels of the table.

use std::collections::HashMap;
use std::sync::RwLock;

use crate::embedder::{Embedding, TextEmbedder, normalize_all};
use crate::error::{Result, TextError};

/// A [`TextEmbedder`] with a memo of the labels it has embedded. Share one per process
/// (`Send + Sync`; lookups take a read lock, new labels a short write lock).
#[derive(Debug)]
pub struct LabelCache {
    /// `None`: a table-only cache.
    embedder: Option<TextEmbedder>,
    memo: RwLock<HashMap<String, Embedding>>,
}

impl LabelCache {
    /// An empty cache around `embedder`.
    pub fn new(embedder: TextEmbedder) -> Self {
        Self { embedder: Some(embedder), memo: RwLock::new(HashMap::new()) }
    }

    /// A cache that knows exactly the labels of `table` (label → embedding, as
    /// [`LabelCache::entries`] gave them) and has no model to embed others.
    pub fn from_table(table: impl IntoIterator<Item = (String, Embedding)>) -> Self {
        Self { embedder: None, memo: RwLock::new(table.into_iter().collect()) }
    }

    /// Every memoized label with its embedding, sorted by label: what [`LabelCache::from_table`]
    /// takes back.
    pub fn entries(&self) -> Vec<(String, Embedding)> {
        let memo = self.memo.read().unwrap_or_else(|e| e.into_inner());
        let mut out: Vec<(String, Embedding)> = memo.iter().map(|(l, e)| (l.clone(), *e)).collect();
        out.sort_unstable_by(|a, b| a.0.cmp(&b.0));
        out
    }

    /// The embedder, for text that should not be memoized (queries); an error for a
    /// table-only cache.
    pub fn embedder(&self) -> Result<&TextEmbedder> {
        self.embedder.as_ref().ok_or_else(|| TextError::TableOnly { labels: vec![] })
    }

    /// Embeddings of `labels`, in order. Labels not seen before are embedded in one batch and
    /// remembered; an empty label is an error and nothing is embedded.
    pub fn embed(&self, labels: &[&str]) -> Result<Vec<Embedding>> {
        let labels = normalize_all(labels)?;
        let mut missing: Vec<&str> = {
            let memo = self.memo.read().unwrap_or_else(|e| e.into_inner());
            labels.iter().copied().filter(|l| !memo.contains_key(*l)).collect()
        };
        if !missing.is_empty() {
            missing.sort_unstable();
            missing.dedup();
            let embedder = self.embedder.as_ref().ok_or_else(|| TextError::TableOnly {
                labels: missing.iter().map(|l| l.to_string()).collect(),
            })?;
            let fresh = embedder.embed(&missing)?;
            let mut memo = self.memo.write().unwrap_or_else(|e| e.into_inner());
            for (label, embedding) in missing.into_iter().zip(fresh) {
                memo.insert(label.to_owned(), embedding);
            }
        }
        let memo = self.memo.read().unwrap_or_else(|e| e.into_inner());
        Ok(labels.iter().map(|l| memo[*l]).collect())
    }

    /// How many distinct labels are memoized.
    pub fn len(&self) -> usize {
        self.memo.read().unwrap_or_else(|e| e.into_inner()).len()
    }

    /// Whether no label is memoized yet.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}
