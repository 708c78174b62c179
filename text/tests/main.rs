//! The text crate's integration tests, one test binary: embeddings against a numpy
//! reference and text queries.

#[path = "reference/vectors.rs"]
mod vectors;
mod embeddings;
mod locate;
