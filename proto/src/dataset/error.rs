//! The one dataset error: which file, which field, what is wrong with it.

use std::fmt;
use std::path::PathBuf;

use crate::camera::CameraError;

/// A rejected scene input. Displays as `FILE: FIELD: PROBLEM`.
#[derive(Debug, thiserror::Error)]
pub struct DatasetError {
    pub file: PathBuf,
    /// JSON path of the offending field (`frames[3].transform_matrix`), or the part of a
    /// file (`pixel (4, 7)`) where the problem is.
    pub field: String,
    pub problem: Problem,
}

impl fmt::Display for DatasetError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}: {}", self.file.display(), self.field, self.problem)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum Problem {
    #[error("missing")]
    Missing,
    #[error("cannot read: {0}")]
    Unreadable(String),
    #[error("invalid JSON: {0}")]
    Json(String),
    #[error("path `{0}` leaves the scene folder")]
    PathEscapes(String),
    #[error("not a valid camera transform: {0}")]
    Transform(CameraError),
    #[error("image is {found_w}×{found_h}, but {other} is {expected_w}×{expected_h}")]
    SizeMismatch { found_w: u32, found_h: u32, expected_w: u32, expected_h: u32, other: String },
    #[error("expected {expected}, found {found}")]
    PixelFormat { expected: &'static str, found: String },
    #[error("instance id {id} at pixel ({x}, {y}) is not listed in `instances`")]
    UnknownInstance { id: u16, x: u32, y: u32 },
    #[error("{0}")]
    Invalid(String),
}

impl DatasetError {
    pub fn new(file: impl Into<PathBuf>, field: impl Into<String>, problem: Problem) -> Self {
        Self { file: file.into(), field: field.into(), problem }
    }
}
