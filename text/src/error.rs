//! The crate's error type. Every failure names what it was about: the model folder and how it
//! was looked for, the file that could not be read, or the input text that was rejected, so a
//! caller can print it to a person as it is.

use std::path::PathBuf;

/// Everything that can go wrong loading the model or embedding text.
#[derive(Debug, thiserror::Error)]
pub enum TextError {
    /// No model folder was found. `searched` says where it was looked for, and the message
    /// names the environment variable and the default location.
    #[error(
        "all-MiniLM-L6-v2 text model not found: {searched}. Set {env} to the model folder \
         (model.safetensors, tokenizer.json, config.json) or install it at the default \
         location <workspace>/{default}/ with scripts/setup (then `source .deps/env`)",
        env = crate::MODEL_ENV,
        default = crate::DEFAULT_MODEL_GLOB
    )]
    ModelNotFound {
        /// Where the model was looked for and what was missing.
        searched: String,
    },
    /// A model file exists but could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// config.json is not a BERT configuration this crate can run.
    #[error("bad model config {path}: {reason}")]
    Config {
        /// The config file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// tokenizer.json could not be loaded, or the tokenizer failed on an input.
    #[error("tokenizer: {0}")]
    Tokenizer(String),
    /// The tensor library failed (loading weights or running the network).
    #[error("model: {0}")]
    Candle(#[from] candle_core::Error),
    /// A cache built from a label table (no model loaded) was asked for other text.
    #[error(
        "no text model is loaded (the label cache was built from a table) and the table lacks {labels:?}; \
         load the model with {env} instead",
        env = crate::MODEL_ENV
    )]
    TableOnly {
        /// The labels asked for that the table lacks (empty: free text such as a query).
        labels: Vec<String>,
    },
    /// An input text is empty once surrounding whitespace is trimmed.
    #[error("text #{index} is empty (after trimming whitespace); nothing to embed")]
    EmptyText {
        /// Position of the text in the batch that was passed.
        index: usize,
    },
}

/// Result with [`TextError`].
pub type Result<T> = std::result::Result<T, TextError>;
