//! `inssplat serve` under bad input: more than 40 malformed requests (wrong content types,
//! truncated multipart, non-images, 1 and 17 images, 0×0 and huge images, bad JSON, wrong
//! types, unknown and traversal ids, oversized bodies, bad API keys, hostile archives), each
//! answered with the right 4xx and the one JSON error shape, against the real binary on
//! loopback with a tiny exported network; the service stays up and a valid request succeeds
//! afterwards.

use crate::support;
use crate::support::http::{Server, multipart, png};
use inssplat_proto::api::{QueryResponse, ReconstructResponse};

const KEY: &str = "test-key-3c1f";
const AUTH: (&str, &str) = ("Authorization", "Bearer test-key-3c1f");
const UNKNOWN: &str = "0123456789abcdef0123456789abcdef";

/// A PNG header claiming `w`×`h` (with a valid CRC), followed by nothing.
fn png_header(w: u32, h: u32) -> Vec<u8> {
    let mut bytes = png(1, 1, 0);
    bytes[16..20].copy_from_slice(&w.to_be_bytes());
    bytes[20..24].copy_from_slice(&h.to_be_bytes());
    let crc = crc(&bytes[12..29]);
    bytes[29..33].copy_from_slice(&crc.to_be_bytes());
    bytes
}

fn crc(data: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in data {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 == 1 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

/// A tar archive (made by the system's `tar`) of `files` (path, bytes) under a temp folder.
fn tar_of(files: &[(&str, &[u8])]) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    for (path, bytes) in files {
        let p = dir.path().join("root").join(path);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    }
    let out = dir.path().join("a.tar");
    let ok = std::process::Command::new("tar")
        .args(["-cf", out.to_str().unwrap(), "-C", dir.path().join("root").to_str().unwrap(), "."])
        .status()
        .unwrap();
    assert!(ok.success());
    std::fs::read(out).unwrap()
}

/// A tar whose only entry is named `../escape.png` (written by hand: tools refuse to).
fn traversal_tar() -> Vec<u8> {
    let mut header = [0u8; 512];
    let name = b"../escape.png";
    header[..name.len()].copy_from_slice(name);
    header[100..108].copy_from_slice(b"0000644\0");
    header[108..116].copy_from_slice(b"0000000\0");
    header[116..124].copy_from_slice(b"0000000\0");
    header[124..136].copy_from_slice(b"00000000004\0");
    header[136..148].copy_from_slice(b"00000000000\0");
    header[156] = b'0';
    header[257..263].copy_from_slice(b"ustar\0");
    header[263..265].copy_from_slice(b"00");
    header[148..156].copy_from_slice(b"        ");
    let sum: u32 = header.iter().map(|&b| u32::from(b)).sum();
    header[148..156].copy_from_slice(format!("{sum:06o}\0 ").as_bytes());
    let mut out = header.to_vec();
    let mut data = [0u8; 512];
    data[..4].copy_from_slice(b"evil");
    out.extend_from_slice(&data);
    out.extend_from_slice(&[0u8; 1024]);
    out
}

struct Case {
    what: &'static str,
    method: &'static str,
    path: String,
    headers: Vec<(&'static str, String)>,
    body: Vec<u8>,
    status: u16,
    error_type: &'static str,
}

fn case(
    what: &'static str,
    method: &'static str,
    path: &str,
    content_type: Option<&str>,
    body: Vec<u8>,
    status: u16,
    error_type: &'static str,
) -> Case {
    let mut headers = vec![(AUTH.0, AUTH.1.to_string())];
    if let Some(ct) = content_type {
        headers.push(("Content-Type", ct.to_string()));
    }
    Case { what, method, path: path.to_string(), headers, body, status, error_type }
}

fn form(
    what: &'static str,
    path: &str,
    parts: &[(&str, Option<&str>, &[u8])],
    status: u16,
    error_type: &'static str,
) -> Case {
    let (ct, body) = multipart(parts);
    case(what, "POST", path, Some(&ct), body, status, error_type)
}

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

    let img = png(16, 16, 1);
    let one: Vec<(&str, Option<&str>, &[u8])> = vec![("images", Some("a.png"), &img)];
    let seventeen: Vec<(&str, Option<&str>, &[u8])> =
        (0..17).map(|_| ("images", Some("a.png"), img.as_slice())).collect();
    let zero = png_header(0, 0);
    let huge = png_header(20_000, 20_000);
    let mut cut = png(64, 64, 2);
    cut.truncate(cut.len() / 2);
    let (ct_ok, full) =
        multipart(&[("images", Some("a.png"), &img), ("images", Some("b.png"), &img)]);
    let truncated = full[..full.len() - 40].to_vec();
    let big = vec![b'x'; 2 << 20];
    let (ct_big, big_form) =
        multipart(&[("images", Some("a.png"), &big), ("images", Some("b.png"), &img)]);
    let q = format!("/v1/scenes/{scene}/query");
    let json = Some("application/json");
    let bad_tar = traversal_tar();
    let good_tar = tar_of(&[("s/a.png", &img), ("s/b.png", &img)]);
    let junk_tar = tar_of(&[("notes/readme.txt", b"no photos here")]);
    let mut zip_junk = b"PK\x03\x04".to_vec();
    zip_junk.extend_from_slice(&[0xff; 64]);

    let mut cases = vec![
        case(
            "json to a multipart route",
            "POST",
            "/v1/reconstruct",
            json,
            b"{}".to_vec(),
            415,
            "unsupported_media_type",
        ),
        case(
            "no content type",
            "POST",
            "/v1/reconstruct",
            None,
            b"abc".to_vec(),
            415,
            "unsupported_media_type",
        ),
        case(
            "text/plain",
            "POST",
            "/v1/reconstruct",
            Some("text/plain"),
            b"abc".to_vec(),
            415,
            "unsupported_media_type",
        ),
        case(
            "multipart without boundary",
            "POST",
            "/v1/reconstruct",
            Some("multipart/form-data"),
            full.clone(),
            415,
            "unsupported_media_type",
        ),
        case(
            "truncated multipart",
            "POST",
            "/v1/reconstruct",
            Some(&ct_ok),
            truncated,
            400,
            "bad_request",
        ),
        case(
            "multipart body that is not multipart",
            "POST",
            "/v1/reconstruct",
            Some(&ct_ok),
            b"hello there".to_vec(),
            400,
            "bad_request",
        ),
        form("no images", "/v1/reconstruct", &[("vocab", None, b"lamp")], 422, "validation"),
        form("one image", "/v1/reconstruct", &one, 422, "validation"),
        form("seventeen images", "/v1/reconstruct", &seventeen, 422, "validation"),
        form(
            "non-image bytes",
            "/v1/reconstruct",
            &[("images", Some("a.png"), b"not an image"), ("images", Some("b.png"), &img)],
            422,
            "validation",
        ),
        form(
            "empty files",
            "/v1/reconstruct",
            &[("images", Some("a.png"), b""), ("images", Some("b.png"), b"")],
            422,
            "validation",
        ),
        form(
            "a 0x0 image",
            "/v1/reconstruct",
            &[("images", Some("z.png"), &zero), ("images", Some("b.png"), &img)],
            422,
            "validation",
        ),
        form(
            "huge dimensions",
            "/v1/reconstruct",
            &[("images", Some("h.png"), &huge), ("images", Some("b.png"), &img)],
            422,
            "validation",
        ),
        form(
            "truncated image",
            "/v1/reconstruct",
            &[("images", Some("c.png"), &cut), ("images", Some("b.png"), &img)],
            422,
            "validation",
        ),
        form(
            "unknown field",
            "/v1/reconstruct",
            &[("photos", Some("a.png"), &img), ("images", Some("b.png"), &img)],
            422,
            "validation",
        ),
        form(
            "vocab not UTF-8",
            "/v1/reconstruct",
            &[
                ("images", Some("a.png"), &img),
                ("images", Some("b.png"), &img),
                ("vocab", None, &[0xff, 0xfe]),
            ],
            422,
            "validation",
        ),
        form(
            "vocab with no label",
            "/v1/reconstruct",
            &[
                ("images", Some("a.png"), &img),
                ("images", Some("b.png"), &img),
                ("vocab", None, b" , \n"),
            ],
            422,
            "validation",
        ),
        form(
            "refine_steps not a number",
            "/v1/reconstruct",
            &[
                ("images", Some("a.png"), &img),
                ("images", Some("b.png"), &img),
                ("refine_steps", None, b"many"),
            ],
            422,
            "validation",
        ),
        form(
            "refine_steps over the limit",
            "/v1/reconstruct",
            &[
                ("images", Some("a.png"), &img),
                ("images", Some("b.png"), &img),
                ("refine_steps", None, b"1001"),
            ],
            422,
            "validation",
        ),
        case(
            "oversized body",
            "POST",
            "/v1/reconstruct",
            Some(&ct_big),
            big_form.clone(),
            413,
            "payload_too_large",
        ),
        case("query: bad JSON", "POST", &q, json, b"{\"text\": ".to_vec(), 400, "bad_request"),
        case("query: wrong type", "POST", &q, json, b"{\"text\": 5}".to_vec(), 422, "validation"),
        case("query: missing field", "POST", &q, json, b"{}".to_vec(), 422, "validation"),
        case("query: JSON null", "POST", &q, json, b"null".to_vec(), 422, "validation"),
        case(
            "query: unknown field",
            "POST",
            &q,
            json,
            b"{\"text\": \"lamp\", \"limit\": 3}".to_vec(),
            422,
            "validation",
        ),
        case(
            "query: empty text",
            "POST",
            &q,
            json,
            b"{\"text\": \"  \"}".to_vec(),
            422,
            "validation",
        ),
        case(
            "query: text too long",
            "POST",
            &q,
            json,
            format!("{{\"text\": \"{}\"}}", "a".repeat(600)).into_bytes(),
            422,
            "validation",
        ),
        case(
            "query: text/plain",
            "POST",
            &q,
            Some("text/plain"),
            b"lamp".to_vec(),
            415,
            "unsupported_media_type",
        ),
        case(
            "query: oversized JSON",
            "POST",
            &q,
            json,
            format!("{{\"text\": \"{}\"}}", "a".repeat(2 << 20)).into_bytes(),
            413,
            "payload_too_large",
        ),
        case(
            "query: unknown scene",
            "POST",
            &format!("/v1/scenes/{UNKNOWN}/query"),
            json,
            b"{\"text\": \"lamp\"}".to_vec(),
            404,
            "not_found",
        ),
        case(
            "query: traversal id",
            "POST",
            "/v1/scenes/..%2F..%2Fetc/query",
            json,
            b"{\"text\": \"lamp\"}".to_vec(),
            400,
            "bad_request",
        ),
        case(
            "ply: unknown scene",
            "GET",
            &format!("/v1/scenes/{UNKNOWN}/scene.ply"),
            None,
            vec![],
            404,
            "not_found",
        ),
        case(
            "ply: malformed id",
            "GET",
            "/v1/scenes/ABC/scene.ply",
            None,
            vec![],
            400,
            "bad_request",
        ),
        case(
            "ply: encoded traversal id",
            "GET",
            "/v1/scenes/%2e%2e%2f%2e%2e%2fetc%2fpasswd/scene.ply",
            None,
            vec![],
            400,
            "bad_request",
        ),
        case(
            "raw traversal path",
            "GET",
            "/v1/scenes/../../etc/passwd",
            None,
            vec![],
            404,
            "not_found",
        ),
        case(
            "view not a number",
            "GET",
            &format!("/v1/scenes/{scene}/views/abc/instances.png"),
            None,
            vec![],
            400,
            "bad_request",
        ),
        case(
            "view out of range",
            "GET",
            &format!("/v1/scenes/{scene}/views/99/labels.png"),
            None,
            vec![],
            404,
            "not_found",
        ),
        case(
            "negative view",
            "GET",
            &format!("/v1/scenes/{scene}/views/-1/labels.png"),
            None,
            vec![],
            400,
            "bad_request",
        ),
        case(
            "mask: bad file name",
            "GET",
            &format!("/v1/scenes/{scene}/query/lamp/..%2Fscene.ply"),
            None,
            vec![],
            400,
            "bad_request",
        ),
        case(
            "mask: bad folder",
            "GET",
            &format!("/v1/scenes/{scene}/query/..%2F..%2F/id1_view000.png"),
            None,
            vec![],
            400,
            "bad_request",
        ),
        case(
            "preview: unknown scene",
            "GET",
            &format!("/v1/scenes/{UNKNOWN}/preview.png"),
            None,
            vec![],
            404,
            "not_found",
        ),
        case(
            "job: unknown id",
            "GET",
            &format!("/v1/jobs/{UNKNOWN}"),
            None,
            vec![],
            404,
            "not_found",
        ),
        case("job: malformed id", "GET", "/v1/jobs/not-a-job", None, vec![], 400, "bad_request"),
        case(
            "job: cancel unknown",
            "DELETE",
            &format!("/v1/jobs/{UNKNOWN}"),
            None,
            vec![],
            404,
            "not_found",
        ),
        case(
            "job: events of malformed id",
            "GET",
            "/v1/jobs/..%2F..%2Fjobs.sqlite/events",
            None,
            vec![],
            400,
            "bad_request",
        ),
        case(
            "job: events of unknown job",
            "GET",
            &format!("/v1/jobs/{UNKNOWN}/events"),
            None,
            vec![],
            404,
            "not_found",
        ),
        case(
            "job: text/plain",
            "POST",
            "/v1/jobs",
            Some("text/plain"),
            b"scenes".to_vec(),
            415,
            "unsupported_media_type",
        ),
        case(
            "job: body not an archive",
            "POST",
            "/v1/jobs",
            Some("application/x-tar"),
            b"plain bytes".to_vec(),
            422,
            "validation",
        ),
        case(
            "job: corrupt zip",
            "POST",
            "/v1/jobs",
            Some("application/zip"),
            zip_junk,
            422,
            "validation",
        ),
        case(
            "job: traversal tar",
            "POST",
            "/v1/jobs",
            Some("application/x-tar"),
            bad_tar,
            422,
            "validation",
        ),
        case(
            "job: tar with no scene",
            "POST",
            "/v1/jobs",
            Some("application/x-tar"),
            junk_tar,
            422,
            "validation",
        ),
        case(
            "job: oversized archive",
            "POST",
            "/v1/jobs",
            Some("application/x-tar"),
            big.clone(),
            413,
            "payload_too_large",
        ),
        form("job: no scenes", "/v1/jobs", &[("vocab", None, b"lamp")], 422, "validation"),
        form(
            "job: scene with one photo",
            "/v1/jobs",
            &[("kitchen", Some("a.png"), &img)],
            422,
            "validation",
        ),
        form(
            "job: bad scene name",
            "/v1/jobs",
            &[("../x", Some("a.png"), &img), ("../x", Some("b.png"), &img)],
            422,
            "validation",
        ),
        form(
            "job: archive and photo sets",
            "/v1/jobs",
            &[
                ("archive", Some("a.tar"), &good_tar),
                ("s", Some("a.png"), &img),
                ("s", Some("b.png"), &img),
            ],
            422,
            "validation",
        ),
        form(
            "job: negative refine_steps",
            "/v1/jobs",
            &[
                ("s", Some("a.png"), &img),
                ("s", Some("b.png"), &img),
                ("refine_steps", None, b"-5"),
            ],
            422,
            "validation",
        ),
        form(
            "job: photo set with a non-image",
            "/v1/jobs",
            &[("s", Some("a.png"), &img), ("s", Some("b.txt"), b"text")],
            422,
            "validation",
        ),
        case("wrong method", "GET", "/v1/reconstruct", None, vec![], 405, "method_not_allowed"),
        case(
            "wrong method on a job",
            "PUT",
            &format!("/v1/jobs/{UNKNOWN}"),
            None,
            vec![],
            405,
            "method_not_allowed",
        ),
        case("unknown route", "GET", "/v2/reconstruct", None, vec![], 404, "not_found"),
    ];
    let (ct_two, two) =
        multipart(&[("images", Some("a.png"), &img), ("images", Some("b.png"), &img)]);
    let mut no_key = case(
        "missing API key",
        "POST",
        "/v1/reconstruct",
        Some(&ct_two),
        two.clone(),
        401,
        "unauthorized",
    );
    no_key.headers.retain(|(k, _)| *k != "Authorization");
    let mut wrong_key = case(
        "wrong API key",
        "POST",
        "/v1/reconstruct",
        Some(&ct_two),
        two.clone(),
        401,
        "unauthorized",
    );
    wrong_key.headers[0].1 = "Bearer test-key-3c1e".into();
    let mut basic = case(
        "basic auth instead of bearer",
        "GET",
        &format!("/v1/jobs/{UNKNOWN}"),
        None,
        vec![],
        401,
        "unauthorized",
    );
    basic.headers[0].1 = format!("Basic {KEY}");
    let mut prefix = case(
        "a prefix of the key",
        "GET",
        &format!("/v1/scenes/{scene}/scene.ply"),
        None,
        vec![],
        401,
        "unauthorized",
    );
    prefix.headers[0].1 = "Bearer test-key".into();
    cases.extend([no_key, wrong_key, basic, prefix]);
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
