//! `GET /v1/scenes/{id}/archive`: a stored scene's whole folder as one zip (`<id>/scene.ply`,
//! `<id>/transforms.json`, `<id>/images/…`, masks, `instances.json`, query masks), the same
//! files `inssplat reconstruct` writes, so the unpacked folder opens in nerfstudio-style tools
//! as it is. The store's own markers (dot files) stay out. The zip is streamed as it is
//! written, file by file, so a scene of large photos never sits in memory whole.

use std::io::{BufWriter, Write};
use std::path::Path as FsPath;
use std::sync::Arc;

use axum::body::Body;
use axum::extract::rejection::PathRejection;
use axum::extract::{Path, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use inssplat_proto::api::ErrorBody;
use tokio::sync::mpsc;
use zip::CompressionMethod;
use zip::write::SimpleFileOptions;

use super::scenes::scene_dir;
use super::{ApiError, AppState};

/// The scene's folder as a zip archive.
#[utoipa::path(get, path = "/v1/scenes/{id}/archive", tag = "scenes",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Scene id (32 hex digits)")),
    responses((status = 200, description = "Zip of the scene's folder (PLY, transforms.json with its photos, masks, instances.json)", content_type = "application/zip"),
        (status = 400, description = "Malformed id", body = ErrorBody), (status = 404, description = "No such scene", body = ErrorBody)))]
pub async fn archive(
    State(state): State<Arc<AppState>>,
    id: Result<Path<String>, PathRejection>,
) -> Result<Response, ApiError> {
    let (id, dir) = scene_dir(&state, &id?.0)?;
    let top = id.to_string();
    let (tx, rx) = mpsc::channel::<std::io::Result<Vec<u8>>>(CHUNKS_IN_FLIGHT);
    tokio::task::spawn_blocking(move || {
        let out = BufWriter::with_capacity(CHUNK, ChunkSender(tx.clone()));
        if let Err(e) = zip_folder(&dir, &top, out) {
            // The client sees the body end in an error rather than a short, valid-looking zip.
            tracing::error!("archiving scene {top}: {e:#}");
            let _ = tx.blocking_send(Err(std::io::Error::other(format!("{e:#}"))));
        }
    });
    let chunks = futures_util::stream::unfold(rx, |mut rx| async move {
        rx.recv().await.map(|chunk| (chunk, rx))
    });
    let disposition = format!("attachment; filename=\"inssplat-{id}.zip\"");
    Ok((
        [
            (header::CONTENT_TYPE, "application/zip".to_string()),
            (header::CONTENT_DISPOSITION, disposition),
        ],
        Body::from_stream(chunks),
    )
        .into_response())
}

/// Bytes per chunk of the response body.
const CHUNK: usize = 256 * 1024;

/// Chunks written ahead of the client before the writer waits for it.
const CHUNKS_IN_FLIGHT: usize = 4;

/// The blocking zip writer's side of the response body: each write becomes a chunk (after
/// the `BufWriter` around it gathers them); a client that went away fails the write.
struct ChunkSender(mpsc::Sender<std::io::Result<Vec<u8>>>);

impl Write for ChunkSender {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0
            .blocking_send(Ok(buf.to_vec()))
            .map_err(|_| std::io::Error::new(std::io::ErrorKind::BrokenPipe, "client went away"))?;
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Every file under `dir` but dot files, in name order, under the folder `top` of a zip
/// written to `out` as it goes. Photos and PNGs are stored as they are (already compressed);
/// the rest is deflated.
fn zip_folder(dir: &FsPath, top: &str, out: impl Write) -> anyhow::Result<()> {
    let mut zip = zip::ZipWriter::new_stream(out);
    let walk = walkdir::WalkDir::new(dir)
        .sort_by_file_name()
        .into_iter()
        .filter_entry(|e| e.depth() == 0 || !e.file_name().to_string_lossy().starts_with('.'));
    for entry in walk {
        let entry = entry?;
        if !entry.file_type().is_file() {
            continue;
        }
        let rel = entry.path().strip_prefix(dir)?;
        let name = rel
            .components()
            .fold(top.to_string(), |name, c| format!("{name}/{}", c.as_os_str().to_string_lossy()));
        let packed = matches!(
            rel.extension().and_then(|e| e.to_str()),
            Some("png" | "jpg" | "jpeg" | "webp")
        );
        let method = if packed { CompressionMethod::Stored } else { CompressionMethod::Deflated };
        zip.start_file(name, SimpleFileOptions::default().compression_method(method))?;
        zip.write_all(&std::fs::read(entry.path())?)?;
    }
    zip.finish()?.into_inner().flush()?;
    Ok(())
}
