//! The malformed requests, each with the status and error type it must get: content types,
//! multipart, images, form fields, queries, ids, archives, methods and API keys.

use super::inputs::{png_header, tar_of, traversal_tar};
use super::{AUTH, KEY, UNKNOWN};
use crate::support::http::{multipart, png};

pub(super) struct Case {
    pub(super) what: &'static str,
    pub(super) method: &'static str,
    pub(super) path: String,
    pub(super) headers: Vec<(&'static str, String)>,
    pub(super) body: Vec<u8>,
    pub(super) status: u16,
    pub(super) error_type: &'static str,
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

/// Every case, against the scene `scene` that the server holds.
pub(super) fn all(scene: &str) -> Vec<Case> {
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
    // The ftyp box a phone's HEIC photo opens with.
    let heic = [b"\0\0\0\x18ftypheic\0\0\0\0mif1heic".as_slice(), &[0; 64]].concat();
    let strip = png(1, 4000, 3);
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
            "a phone's HEIC photo",
            "/v1/reconstruct",
            &[("images", Some("IMG_1.HEIC"), &heic), ("images", Some("b.png"), &img)],
            415,
            "unsupported_media_type",
        ),
        form(
            "a 1×4000 strip",
            "/v1/reconstruct",
            &[("images", Some("strip.png"), &strip), ("images", Some("b.png"), &img)],
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
    cases
}
