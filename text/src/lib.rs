//! inssplat-text: sentence embeddings of label and query text with all-MiniLM-L6-v2
//! (tokenizer from tokenizer.json, BERT through candle-transformers, mean pooling over the
//! attention mask, L2 norm, 384-d). Used by the trainer as the semantic teacher and by the
//! server for labels and queries. It knows nothing of scenes or HTTP.
