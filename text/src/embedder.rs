//! The sentence embedder: all-MiniLM-L6-v2 loaded from a model folder (model.safetensors,
//! tokenizer.json, config.json) and run on the CPU with candle-transformers' BERT. A batch is
//! tokenized at once, sorted by token count and cut into chunks so padding stays small; each
//! chunk is padded on the right with an attention mask, so a text's vector does not depend on
//! what it was batched with. The last hidden states are mean-pooled over the mask and
//! L2-normalized to 384-d unit vectors.

use std::fmt;
use std::path::{Path, PathBuf};

use candle_core::{DType, Device, Tensor};
use candle_nn::VarBuilder;
use candle_transformers::models::bert::{BertModel, Config};
use tokenizers::{Encoding, Tokenizer, TruncationParams};

use crate::error::{Result, TextError};
use crate::locate::{CONFIG_FILE, TOKENIZER_FILE, WEIGHTS_FILE, locate_model, missing_file};

/// Length of an embedding.
pub const EMBEDDING_DIM: usize = 384;

/// One text's embedding: unit length, so the cosine of two is their dot product.
pub type Embedding = [f32; EMBEDDING_DIM];

/// Longest input in tokens (`[CLS]` and `[SEP]` included); longer text is truncated. 256 is the
/// model's `max_seq_length` in sentence_bert_config.json, what sentence-transformers uses.
pub const MAX_TOKENS: usize = 256;

/// Texts per forward pass: bounds memory for long inputs and keeps padding local.
const CHUNK: usize = 32;

/// all-MiniLM-L6-v2 ready to embed text. Cheap to share (`&self` methods, `Send + Sync`);
/// load it once per process.
pub struct TextEmbedder {
    tokenizer: Tokenizer,
    model: BertModel,
    dir: PathBuf,
}

impl fmt::Debug for TextEmbedder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TextEmbedder").field("dir", &self.dir).finish_non_exhaustive()
    }
}

/// `text` with surrounding whitespace removed, or `None` when nothing is left. Whitespace
/// inside is left to the tokenizer, which splits on it.
pub(crate) fn normalize(text: &str) -> Option<&str> {
    let t = text.trim();
    (!t.is_empty()).then_some(t)
}

/// The normalized form of every text, or the index of the first empty one.
pub(crate) fn normalize_all<'a>(texts: &[&'a str]) -> Result<Vec<&'a str>> {
    texts
        .iter()
        .enumerate()
        .map(|(index, t)| normalize(t).ok_or(TextError::EmptyText { index }))
        .collect()
}

impl TextEmbedder {
    /// Loads the model from `INSSPLAT_TEXT_MODEL` or the default location (see
    /// [`locate_model`](crate::locate_model)).
    pub fn from_env() -> Result<Self> {
        Self::load(&locate_model()?)
    }

    /// Loads the model from `dir`.
    pub fn load(dir: &Path) -> Result<Self> {
        if let Some(why) = missing_file(dir) {
            return Err(TextError::ModelNotFound { searched: why });
        }
        let config_path = dir.join(CONFIG_FILE);
        let config_text = std::fs::read_to_string(&config_path)
            .map_err(|source| TextError::Io { path: config_path.clone(), source })?;
        let config: Config = serde_json::from_str(&config_text)
            .map_err(|e| TextError::Config { path: config_path.clone(), reason: e.to_string() })?;
        if config.hidden_size != EMBEDDING_DIM {
            return Err(TextError::Config {
                path: config_path,
                reason: format!("hidden_size is {}, expected {EMBEDDING_DIM}", config.hidden_size),
            });
        }

        let tokenizer_path = dir.join(TOKENIZER_FILE);
        let mut tokenizer = Tokenizer::from_file(&tokenizer_path)
            .map_err(|e| TextError::Tokenizer(format!("{}: {e}", tokenizer_path.display())))?;
        // tokenizer.json pads every input to 128 tokens; padding is done per chunk instead.
        tokenizer.with_padding(None);
        tokenizer
            .with_truncation(Some(TruncationParams {
                max_length: MAX_TOKENS,
                ..Default::default()
            }))
            .map_err(|e| TextError::Tokenizer(e.to_string()))?;

        let weights_path = dir.join(WEIGHTS_FILE);
        let weights = std::fs::read(&weights_path)
            .map_err(|source| TextError::Io { path: weights_path, source })?;
        let vb = VarBuilder::from_buffered_safetensors(weights, DType::F32, &Device::Cpu)?;
        let model = BertModel::load(vb, &config)?;
        Ok(Self { tokenizer, model, dir: dir.to_path_buf() })
    }

    /// The folder the model was loaded from.
    pub fn model_dir(&self) -> &Path {
        &self.dir
    }

    /// Embeds one text (trimmed; empty is an error).
    pub fn embed_one(&self, text: &str) -> Result<Embedding> {
        Ok(self.embed(&[text])?[0])
    }

    /// Embeds texts, in order. Each is trimmed; an empty one is [`TextError::EmptyText`] and
    /// nothing is embedded. The vectors equal those of embedding each text alone.
    pub fn embed(&self, texts: &[&str]) -> Result<Vec<Embedding>> {
        let texts = normalize_all(texts)?;
        if texts.is_empty() {
            return Ok(Vec::new());
        }
        let encodings = self
            .tokenizer
            .encode_batch_fast(texts, true)
            .map_err(|e| TextError::Tokenizer(e.to_string()))?;
        let mut order: Vec<usize> = (0..encodings.len()).collect();
        order.sort_by_key(|&i| encodings[i].len());
        let mut out = vec![[0.0; EMBEDDING_DIM]; encodings.len()];
        for chunk in order.chunks(CHUNK) {
            let batch: Vec<&Encoding> = chunk.iter().map(|&i| &encodings[i]).collect();
            for (&i, embedding) in chunk.iter().zip(self.forward(&batch)?) {
                out[i] = embedding;
            }
        }
        Ok(out)
    }

    /// Runs one right-padded batch and pools it.
    fn forward(&self, batch: &[&Encoding]) -> Result<Vec<Embedding>> {
        let rows = batch.len();
        let len = batch.iter().map(|e| e.len()).max().unwrap_or(0);
        let mut ids = vec![0u32; rows * len];
        let mut mask = vec![0u32; rows * len];
        for (r, enc) in batch.iter().enumerate() {
            ids[r * len..r * len + enc.len()].copy_from_slice(enc.get_ids());
            mask[r * len..r * len + enc.len()].copy_from_slice(enc.get_attention_mask());
        }
        let ids = Tensor::from_vec(ids, (rows, len), &Device::Cpu)?;
        let type_ids = ids.zeros_like()?;
        let mask_t = Tensor::from_vec(mask.clone(), (rows, len), &Device::Cpu)?;
        let hidden = self.model.forward(&ids, &type_ids, Some(&mask_t))?;
        let hidden = hidden.flatten_all()?.to_vec1::<f32>()?;
        // Every encoding holds [CLS] and [SEP], so `len` is at least 2.
        Ok(hidden
            .chunks_exact(len * EMBEDDING_DIM)
            .zip(mask.chunks_exact(len))
            .map(|(states, mask)| pool(states, mask))
            .collect())
    }
}

/// Mean of the token states (`mask.len()` rows of [`EMBEDDING_DIM`]) where the mask is set,
/// scaled to unit length.
fn pool(states: &[f32], mask: &[u32]) -> Embedding {
    let mut sum = [0.0f32; EMBEDDING_DIM];
    for (token, _) in states.chunks_exact(EMBEDDING_DIM).zip(mask).filter(|(_, m)| **m != 0) {
        for (s, x) in sum.iter_mut().zip(token) {
            *s += x;
        }
    }
    // The mean's divisor cancels in the normalization; the clamp only guards a zero vector.
    let norm = sum.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
    sum.map(|x| x / norm)
}
