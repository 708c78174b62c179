//! `inssplat serve` under bad input: more than 40 malformed requests (wrong content types,
//! truncated multipart, non-images, 1 and 17 images, 0×0 and huge images, bad JSON, wrong
//! types, unknown and traversal ids, oversized bodies, bad API keys, hostile archives), each
//! answered with the right 4xx and the one JSON error shape, against the real binary on
//! loopback with a tiny exported network; the service stays up and a valid request succeeds
//! afterwards.

mod cases;
mod inputs;

use crate::support;
use crate::support::http::{Server, multipart, png};
use inssplat_proto::api::{QueryResponse, ReconstructResponse};

const KEY: &str = "test-key-3c1f";
const AUTH: (&str, &str) = ("Authorization", "Bearer test-key-3c1f");
const UNKNOWN: &str = "0123456789abcdef0123456789abcdef";

#[test]
fn malformed_requests_get_json_4xx_and_the_service_stays_up() {
    let dir = tempfile::tempdir().unwrap();
    let model = support::tiny_model(dir.path());
    let mut server =
        Server::start(&model, &dir.path().join("data"), &["--api-key", KEY, "--max-body-mb", "1"]);

    // A valid scene first, so artefact and query routes have something to miss.
    let photos: Vec<Vec<u8>> = (0..3).map(|i| png(40, 30, i)).collect();
    let parts: Vec<(&str, Option<&str>, &[u8])> =
        photos.iter().map(|p| ("images", Some("p.png"), p.as_slice())).collect();
    let (ct, body) = multipart(&parts);
    let ok = server.send("POST", "/v1/reconstruct", &[AUTH, ("Content-Type", &ct)], &body);
    assert_eq!(ok.status, 200, "{}", ok.text());
    let scene = ok.json::<ReconstructResponse>().scene_id;

    let cases = cases::all(&scene);
    assert!(cases.len() >= 40, "{} cases", cases.len());

    let mut failures = Vec::new();
    for c in &cases {
        let headers: Vec<(&str, &str)> = c.headers.iter().map(|(k, v)| (*k, v.as_str())).collect();
        let r = server.send(c.method, &c.path, &headers, &c.body);
        if r.status != c.status || r.header("content-type") != Some("application/json") {
            failures.push(format!(
                "{}: {} {} → {} {}",
                c.what,
                c.method,
                c.path,
                r.status,
                r.text()
            ));
            continue;
        }
        let e = r.error();
        if e.error_type != c.error_type {
            failures.push(format!(
                "{}: error_type {} (expected {}): {}",
                c.what, e.error_type, c.error_type, e.error
            ));
        }
        if c.status == 401 {
            assert_eq!(r.header("www-authenticate"), Some("Bearer"));
            assert!(
                !e.error.contains(KEY) && !e.error.contains("3c1e"),
                "the key is echoed: {}",
                e.error
            );
        }
        assert!(server.alive(), "the service died on: {}", c.what);
    }
    assert!(
        failures.is_empty(),
        "{} of {} cases wrong:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
    assert!(!server.log_text().contains(KEY), "the API key was logged");
    assert!(
        !dir.path().join("data").join("escape.png").exists()
            && !dir.path().join("escape.png").exists()
    );

    // Still up: a valid reconstruction and query succeed, artefacts are served.
    let again = server.send("POST", "/v1/reconstruct", &[AUTH, ("Content-Type", &ct)], &body);
    assert_eq!(again.status, 200, "{}", again.text());
    let again = again.json::<ReconstructResponse>();
    assert_eq!(again.cameras.len(), 3);
    let answer = server.send(
        "POST",
        &format!("/v1/scenes/{}/query", again.scene_id),
        &[AUTH, ("Content-Type", "application/json")],
        br#"{"text": "lamp"}"#,
    );
    assert_eq!(answer.status, 200, "{}", answer.text());
    assert_eq!(answer.json::<QueryResponse>().text, "lamp");
    let ply = server.send("GET", &format!("/v1/scenes/{}/scene.ply", again.scene_id), &[AUTH], b"");
    assert_eq!(ply.status, 200);
    assert!(ply.body.starts_with(b"ply\n"));
    let health = server.get("/health");
    assert_eq!(health.status, 200, "health is open without the key");
}

#[test]
fn a_request_over_the_timeout_gets_504_and_the_service_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let model = support::tiny_model(dir.path());
    let server = Server::start(&model, &dir.path().join("data"), &["--request-timeout-s", "1"]);
    // A client that announces a body and sends only part of it holds the handler past the limit.
    let (ct, body) = multipart(&[
        ("images", Some("a.png"), &png(16, 16, 0)),
        ("images", Some("b.png"), &png(16, 16, 1)),
    ]);
    let head = format!(
        "POST /v1/reconstruct HTTP/1.1\r\nHost: x\r\nContent-Type: {ct}\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    let mut raw = head.into_bytes();
    raw.extend_from_slice(&body[..body.len() / 2]);
    let start = std::time::Instant::now();
    let r = server.try_raw(&raw).unwrap();
    assert_eq!(r.status, 504, "{}", r.text());
    assert_eq!(r.error().error_type, "timeout");
    assert!(start.elapsed() < std::time::Duration::from_secs(10));
    let ok = server.send("POST", "/v1/reconstruct", &[("Content-Type", &ct)], &body);
    assert_eq!(ok.status, 200, "{}", ok.text());
}
