//! The web page: `GET /` (upload photos, look at the Gaussians, query them), `GET /jobs`
//! (batch jobs), the page's own files under `/web/` (compiled into the binary from the
//! repository's `web/` folder), and the npm packages it imports (three.js, Spark, redoc) under
//! `/vendor/`, read at run time from `--web-dir` (the `node_modules` that `scripts/setup`
//! installs). Nothing is loaded from elsewhere: the browser needs no network but this service.

use std::path::{Component, Path as FsPath, PathBuf};
use std::sync::Arc;

use axum::extract::{Path, State};
use axum::http::header;
use axum::response::{Html, IntoResponse, Response};

use super::{ApiError, AppState};

/// The page's files: name, content type, text.
const PAGE_FILES: &[(&str, &str, &str)] = &[
    ("style.css", "text/css; charset=utf-8", include_str!("../../../web/style.css")),
    ("api.js", "text/javascript; charset=utf-8", include_str!("../../../web/api.js")),
    ("app.js", "text/javascript; charset=utf-8", include_str!("../../../web/app.js")),
    ("colours.js", "text/javascript; charset=utf-8", include_str!("../../../web/colours.js")),
    ("jobs.js", "text/javascript; charset=utf-8", include_str!("../../../web/jobs.js")),
    ("ply.js", "text/javascript; charset=utf-8", include_str!("../../../web/ply.js")),
    ("viewer.js", "text/javascript; charset=utf-8", include_str!("../../../web/viewer.js")),
    ("views.js", "text/javascript; charset=utf-8", include_str!("../../../web/views.js")),
];

/// The bundled example photos (a procedural test room, four views).
const EXAMPLES: &[(&str, &[u8])] = &[
    ("000.png", include_bytes!("../../../web/example/000.png")),
    ("001.png", include_bytes!("../../../web/example/001.png")),
    ("002.png", include_bytes!("../../../web/example/002.png")),
    ("003.png", include_bytes!("../../../web/example/003.png")),
];

/// What the pages import from `--web-dir`; the pages say which one is missing.
const VENDOR_ENTRIES: &[&str] = &[
    "three/build/three.module.js",
    "@sparkjsdev/spark/dist/spark.module.js",
    "redoc/bundles/redoc.standalone.js",
];

/// Where in a page the warning about missing packages goes.
const NOTICE_SLOT: &str = "<!--vendor-notice-->";

/// The pages may load nothing from any other host (redoc, for one, would fetch its logo from
/// its CDN); inline scripts (the import map), eval and WebAssembly, as Spark uses them, stay
/// allowed.
const CONTENT_SECURITY_POLICY: &str = "default-src 'self' data: blob:; \
    script-src 'self' 'unsafe-inline' 'unsafe-eval' 'wasm-unsafe-eval' blob:; style-src 'self' 'unsafe-inline'";

/// The packages of `--web-dir` that are missing, as one sentence (None when all are there).
pub fn missing_vendor(web_dir: &FsPath) -> Option<String> {
    let missing: Vec<&str> =
        VENDOR_ENTRIES.iter().copied().filter(|e| !web_dir.join(e).is_file()).collect();
    (!missing.is_empty()).then(|| {
        format!(
            "the page's npm packages are missing from --web-dir {} ({}): run scripts/setup, or point --web-dir / INSSPLAT_WEB_DIR at the node_modules it installs",
            web_dir.display(),
            missing.join(", ")
        )
    })
}

/// `html` with the missing-package warning (if any) in its notice slot.
fn page(state: &AppState, html: &str) -> Response {
    let notice = missing_vendor(&state.web_dir)
        .map(|m| format!(r#"<p class="notice error">This page cannot work: {}.</p>"#, escape(&m)));
    (
        [(header::CONTENT_SECURITY_POLICY, CONTENT_SECURITY_POLICY)],
        Html(html.replace(NOTICE_SLOT, &notice.unwrap_or_default())),
    )
        .into_response()
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// The scene page: photos in, 3D view, instances and text queries.
pub async fn index(State(state): State<Arc<AppState>>) -> Response {
    page(&state, include_str!("../../../web/index.html"))
}

/// The batch jobs page.
pub async fn jobs(State(state): State<Arc<AppState>>) -> Response {
    page(&state, include_str!("../../../web/jobs.html"))
}

/// The API reference (redoc, from `--web-dir`).
pub async fn docs(State(state): State<Arc<AppState>>) -> Response {
    page(&state, include_str!("../../../web/docs.html"))
}

/// One of the page's own files.
pub async fn asset(Path(name): Path<String>) -> Result<Response, ApiError> {
    let (_, content_type, text) = PAGE_FILES
        .iter()
        .find(|(n, _, _)| *n == name)
        .ok_or_else(|| ApiError::NotFound(format!("no page file `{}`", name.escape_debug())))?;
    Ok(([(header::CONTENT_TYPE, *content_type)], *text).into_response())
}

/// One of the bundled example photos.
pub async fn example(Path(name): Path<String>) -> Result<Response, ApiError> {
    let (_, bytes) = EXAMPLES
        .iter()
        .find(|(n, _)| *n == name)
        .ok_or_else(|| ApiError::NotFound(format!("no example photo `{}`", name.escape_debug())))?;
    Ok(([(header::CONTENT_TYPE, "image/png")], *bytes).into_response())
}

/// A file of an npm package in `--web-dir`; the path may not leave that folder.
pub async fn vendor(
    State(state): State<Arc<AppState>>,
    Path(rel): Path<String>,
) -> Result<Response, ApiError> {
    let path = vendor_path(&state.web_dir, &rel)?;
    match tokio::fs::read(&path).await {
        Ok(bytes) => Ok(([(header::CONTENT_TYPE, content_type(&path))], bytes).into_response()),
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::NotFound | std::io::ErrorKind::IsADirectory
            ) =>
        {
            Err(ApiError::NotFound(
                missing_vendor(&state.web_dir)
                    .unwrap_or_else(|| format!("no file `{}` in --web-dir", rel.escape_debug())),
            ))
        }
        Err(e) => Err(ApiError::internal(format!("reading {}: {e}", path.display()))),
    }
}

/// `dir/rel`, refusing anything but plain names as components.
fn vendor_path(dir: &FsPath, rel: &str) -> Result<PathBuf, ApiError> {
    let rel = FsPath::new(rel);
    if rel.as_os_str().is_empty() || !rel.components().all(|c| matches!(c, Component::Normal(_))) {
        return Err(ApiError::BadRequest(format!(
            "`{}` is not a file path inside --web-dir",
            rel.display()
        )));
    }
    Ok(dir.join(rel))
}

fn content_type(path: &FsPath) -> &'static str {
    match path.extension().and_then(|e| e.to_str()) {
        Some("js" | "mjs") => "text/javascript; charset=utf-8",
        Some("css") => "text/css; charset=utf-8",
        Some("json" | "map") => "application/json",
        Some("wasm") => "application/wasm",
        Some("png") => "image/png",
        _ => "application/octet-stream",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vendor_paths_stay_inside() {
        let dir = FsPath::new("/w");
        assert_eq!(
            vendor_path(dir, "three/build/three.module.js").unwrap(),
            FsPath::new("/w/three/build/three.module.js")
        );
        for bad in ["", "../etc/passwd", "three/../../x", "/etc/passwd", "./three"] {
            assert!(vendor_path(dir, bad).is_err(), "{bad}");
        }
        assert_eq!(content_type(FsPath::new("a/b.mjs")), "text/javascript; charset=utf-8");
    }

    #[test]
    fn missing_packages_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let message = missing_vendor(dir.path()).unwrap();
        assert!(
            message.contains("@sparkjsdev/spark/dist/spark.module.js")
                && message.contains("scripts/setup"),
            "{message}"
        );
    }
}
