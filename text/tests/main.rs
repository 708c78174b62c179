//! The text crate's integration tests, one test binary: embeddings against a numpy
//! reference and text queries.

mod embeddings;
mod locate;
#[path = "reference/vectors.rs"]
mod vectors;
