//! Per-process memo of label embeddings. The server names every scene's instances against the
//! same label vocabulary and the trainer's semantic teacher embeds the same category names
//! every step, so each distinct (trimmed) label is run through the network once and then
//! served from memory. Query text, which rarely repeats, goes to the embedder directly.

use std::collections::HashMap;
use std::sync::RwLock;

use crate::embedder::{Embedding, TextEmbedder, normalize_all};
use crate::error::Result;

/// A [`TextEmbedder`] with a memo of the labels it has embedded. Share one per process
/// (`Send + Sync`; lookups take a read lock, new labels a short write lock).
#[derive(Debug)]
pub struct LabelCache {
    embedder: TextEmbedder,
    memo: RwLock<HashMap<String, Embedding>>,
}

impl LabelCache {
    /// An empty cache around `embedder`.
    pub fn new(embedder: TextEmbedder) -> Self {
        Self {
            embedder,
            memo: RwLock::new(HashMap::new()),
        }
    }

    /// The embedder, for text that should not be memoized (queries).
    pub fn embedder(&self) -> &TextEmbedder {
        &self.embedder
    }

    /// Embeddings of `labels`, in order. Labels not seen before are embedded in one batch and
    /// remembered; an empty label is an error and nothing is embedded.
    pub fn embed(&self, labels: &[&str]) -> Result<Vec<Embedding>> {
        let labels = normalize_all(labels)?;
        let mut missing: Vec<&str> = {
            let memo = self.memo.read().unwrap_or_else(|e| e.into_inner());
            labels
                .iter()
                .copied()
                .filter(|l| !memo.contains_key(*l))
                .collect()
        };
        if !missing.is_empty() {
            missing.sort_unstable();
            missing.dedup();
            let fresh = self.embedder.embed(&missing)?;
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
