//! Reading multipart bodies: every part with its field name, file name and bytes (the body
//! limit applies while reading), and the text parts a request may send: the label vocabulary
//! and the steps of test-time refinement.

use axum::body::Bytes;
use axum::extract::Multipart;

use super::ApiError;

const MAX_LABELS: usize = 1000;
const MAX_LABEL_CHARS: usize = 100;
/// Most steps of test-time refinement a request may ask for (about 50 s at 8 views on two
/// cores, inside the default request timeout).
pub const MAX_REFINE_STEPS: usize = 1000;

/// One part of a multipart body.
pub struct Part {
    pub name: String,
    pub file_name: Option<String>,
    pub bytes: Bytes,
}

/// Every part of `multipart`, refusing more than `max_parts`.
pub async fn read_parts(mut multipart: Multipart, max_parts: usize) -> Result<Vec<Part>, ApiError> {
    let mut parts = Vec::new();
    while let Some(field) = multipart.next_field().await? {
        if parts.len() == max_parts {
            return Err(ApiError::Validation(format!("more than {max_parts} form parts")));
        }
        let name = field.name().unwrap_or_default().to_string();
        let file_name = field.file_name().map(str::to_string);
        let bytes = field.bytes().await?;
        parts.push(Part { name, file_name, bytes });
    }
    Ok(parts)
}

/// The labels of a `vocab` part (comma- or line-separated).
pub fn vocabulary(part: &Part) -> Result<Vec<String>, ApiError> {
    let text = std::str::from_utf8(&part.bytes)
        .map_err(|_| ApiError::Validation("`vocab` is not UTF-8 text".into()))?;
    let labels = inssplat_pipeline::vocab::from_list(text);
    if labels.is_empty() {
        return Err(ApiError::Validation(
            "`vocab` names no label (send labels separated by commas or new lines)".into(),
        ));
    }
    if labels.len() > MAX_LABELS || labels.iter().any(|l| l.chars().count() > MAX_LABEL_CHARS) {
        return Err(ApiError::Validation(format!(
            "`vocab`: at most {MAX_LABELS} labels of at most {MAX_LABEL_CHARS} characters"
        )));
    }
    Ok(labels)
}

/// The steps of a `refine_steps` part: a whole number from 0 to [`MAX_REFINE_STEPS`].
pub fn refine_steps(part: &Part) -> Result<usize, ApiError> {
    let text = String::from_utf8_lossy(&part.bytes);
    text.trim().parse::<usize>().ok().filter(|&n| n <= MAX_REFINE_STEPS).ok_or_else(|| {
        ApiError::Validation(format!(
            "`refine_steps` is `{}`: send a whole number of steps from 0 (none) to {MAX_REFINE_STEPS}",
            text.chars().take(40).collect::<String>().escape_debug()
        ))
    })
}
