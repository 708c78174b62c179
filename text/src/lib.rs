//! inssplat-text: sentence embeddings of label and query text with all-MiniLM-L6-v2
//! (tokenizer from tokenizer.json, BERT through candle-transformers, mean pooling over the
//! attention mask, L2 norm, 384-d). Used by the trainer as the semantic teacher and by the
//! server for labels and queries. It knows nothing of scenes or HTTP.
//!
//! The model folder comes from `INSSPLAT_TEXT_MODEL` or the setup step's default location
//! `<workspace>/.deps/all-minilm-l6-v2-*/` ([`locate_model`]); nothing is downloaded at run
//! time. [`TextEmbedder`] embeds batches on the CPU (texts are trimmed, empty text is an
//! error, padding never changes a vector); [`LabelCache`] memoizes a label vocabulary so
//! each label goes through the network once per process. Vectors have unit length, so
//! [`cosine`] is a dot product.
//!
//! ```no_run
//! use inssplat_text::{LabelCache, TextEmbedder, cosine};
//! let cache = LabelCache::new(TextEmbedder::from_env()?);
//! let labels = cache.embed(&["chair", "table", "lamp"])?;
//! let query = cache.embedder()?.embed_one("something to sit on")?;
//! let best = labels.iter().map(|l| cosine(l, &query)).fold(f32::MIN, f32::max);
//! # Ok::<(), inssplat_text::TextError>(())
//! ```

mod cache;
mod embedder;
mod error;
mod locate;

pub use cache::LabelCache;
pub use embedder::{EMBEDDING_DIM, Embedding, MAX_TOKENS, TextEmbedder};
pub use error::{Result, TextError};
pub use locate::{DEFAULT_MODEL_GLOB, MODEL_ENV, locate_model, locate_model_in};

/// Cosine similarity of two embeddings (their dot product, as both have unit length).
pub fn cosine(a: &Embedding, b: &Embedding) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
