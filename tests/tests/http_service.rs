//! `inssplat serve` doing its job, end to end over loopback with the real binary, a tiny
//! exported network and procedural scenes: a reconstruction and its artefacts, a query with
//! its masks, a batch job of photo sets and of dataset scenes (tar) scored against their
//! ground truth and followed by server-sent events, cancelling, the metrics, the OpenAPI
//! document, and a graceful stop on SIGTERM.

use std::time::Duration;

use crate::support;
use crate::support::http::{Server, multipart, png, scene_photos};
use inssplat_proto::api::{JobAccepted, JobState, JobStatus, QueryResponse, ReconstructResponse};

/// The shipped network (its labels are meaningful, so a query finds what it names).
fn shipped_model() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx")
}

/// `POST /v1/reconstruct` of `photos` with one more text field; the answer must be 200.
fn reconstruct(
    server: &Server,
    photos: &[Vec<u8>],
    (field, value): (&str, &[u8]),
) -> ReconstructResponse {
    let mut parts: Vec<(&str, Option<&str>, &[u8])> =
        photos.iter().map(|p| ("images", Some("v.png"), p.as_slice())).collect();
    parts.push((field, None, value));
    let (ct, body) = multipart(&parts);
    let r = server.send("POST", "/v1/reconstruct", &[("Content-Type", &ct)], &body);
    assert_eq!(r.status, 200, "{}", r.text());
    r.json()
}

#[test]
fn reconstructs_serves_artefacts_and_answers_queries() {
    let dir = tempfile::tempdir().unwrap();
    let model = shipped_model();
    let scene = support::test_scene(dir.path(), 3);
    let server = Server::start(&model, &dir.path().join("data"), &[]);

    let photos = scene_photos(&scene);
    let rec = reconstruct(&server, &photos[..4], ("vocab", b"chair, table\nlamp,wall,floor"));
    assert_eq!(rec.scene_id.len(), 32);
    assert_eq!(rec.cameras.len(), 4);
    // The server registers on the shipped learned matcher and says how well each photo fit.
    assert!(
        rec.cameras.iter().all(|c| c.fit.is_some_and(|f| f.keypoints > 0)),
        "{:?}",
        rec.cameras
    );
    assert!(rec.gaussians_kept > 0 && rec.gaussians_kept <= rec.gaussians_in);
    assert!(
        rec.refinement.is_none() && rec.timings.iter().all(|t| t.stage != "refine"),
        "refined unasked: {:?}",
        rec.timings
    );
    assert!(
        rec.timings.iter().any(|t| t.stage == "rays"),
        "the shipped network reads the registered cameras: {:?}",
        rec.timings
    );
    assert!(
        rec.instances
            .iter()
            .all(|i| ["chair", "table", "lamp", "wall", "floor", "unknown"]
                .contains(&i.label.as_str())),
        "{:?}",
        rec.instances
    );

    let base = format!("/v1/scenes/{}", rec.scene_id);
    let ply = server.get(&format!("{base}/scene.ply"));
    assert_eq!((ply.status, ply.header("content-type")), (200, Some("application/octet-stream")));
    let gaussians = inssplat_proto::ply::read_ply(&mut std::io::Cursor::new(&ply.body)).unwrap();
    assert_eq!(gaussians.len(), rec.gaussians_kept);
    for (v, photo) in photos[..4].iter().enumerate() {
        let photo = image::load_from_memory(photo).unwrap();
        for kind in ["instances", "labels", "ids", "depth"] {
            let img = server.get(&format!("{base}/views/{v}/{kind}.png"));
            assert_eq!(img.status, 200, "{kind} {v}: {}", img.text());
            let img = image::load_from_memory(&img.body).unwrap();
            let size = |i: &image::DynamicImage| (i.width(), i.height());
            assert_eq!(size(&img), size(&photo), "{kind} {v} at the photo's size");
            let sixteen_bit = matches!(img, image::DynamicImage::ImageLuma16(_));
            assert_eq!(sixteen_bit, ["ids", "depth"].contains(&kind), "{kind} {v}");
        }
    }
    let preview = server.get(&format!("{base}/preview.png"));
    assert_eq!((preview.status, preview.header("content-type")), (200, Some("image/png")));
    image::load_from_memory(&preview.body).unwrap();

    // The whole scene as one zip: unpacked anywhere, its transforms.json opens with the photos
    // beside it (the uploads themselves), as nerfstudio-style loaders want.
    let zip = server.get(&format!("{base}/archive"));
    assert_eq!((zip.status, zip.header("content-type")), (200, Some("application/zip")));
    let unpacked = dir.path().join("unpacked");
    zip::ZipArchive::new(std::io::Cursor::new(&zip.body)).unwrap().extract(&unpacked).unwrap();
    let folder = unpacked.join(&rec.scene_id);
    let opened = inssplat_proto::dataset::Scene::load(&folder).unwrap();
    assert_eq!(opened.frames.len(), 4);
    for (v, photo) in photos[..4].iter().enumerate() {
        assert_eq!(&std::fs::read(folder.join(format!("images/{v:03}.png"))).unwrap(), photo);
    }
    assert!(folder.join("scene.ply").is_file() && folder.join("instances.json").is_file());
    assert!(!folder.join(".used").exists(), "the store's marker stays out");
    let unknown = server.get(&format!("/v1/scenes/{}/archive", "0".repeat(32)));
    assert_eq!(unknown.status, 404, "{}", unknown.text());

    // The label of the instance that fits its label best answers with a mask per view.
    let best = rec.instances.iter().max_by(|a, b| a.score.total_cmp(&b.score)).expect("instances");
    let body = format!(r#"{{"text": "{}"}}"#, best.label);
    let q = server.send(
        "POST",
        &format!("{base}/query"),
        &[("Content-Type", "application/json")],
        body.as_bytes(),
    );
    assert_eq!(q.status, 200, "{}", q.text());
    let answer: QueryResponse = q.json();
    assert!(answer.matches.iter().any(|m| m.instance_id == best.id), "{best:?}: {answer:?}");
    for m in &answer.matches {
        assert_eq!(m.masks.len(), 4);
        for mask in &m.masks {
            assert!(mask.png_url.starts_with(&format!("{base}/query/")), "{}", mask.png_url);
            let png = server.get(&mask.png_url);
            assert_eq!(png.status, 200, "{}", mask.png_url);
            let img = image::load_from_memory(&png.body).unwrap().to_luma8();
            let from_png: Vec<bool> = img.pixels().map(|p| p.0[0] > 127).collect();
            assert_eq!(from_png, mask.rle.decode(), "the RLE and the PNG agree");
        }
    }

    let metrics = server.get("/metrics").text();
    for needle in [
        "inssplat_http_requests_total{method=\"POST\",route=\"/v1/reconstruct\",status=\"200\"} 1",
        "inssplat_stage_duration_seconds_count{stage=\"model\"} 1",
        "inssplat_queue_depth 0",
        "inssplat_ready 1",
        "inssplat_jobs{state=\"running\"} 0",
    ] {
        assert!(metrics.contains(needle), "{needle} missing in\n{metrics}");
    }
    let doc: serde_json::Value = server.get("/openapi.json").json();
    assert!(doc["openapi"].as_str().unwrap().starts_with("3."));
    for path in [
        "/v1/reconstruct",
        "/v1/scenes/{id}/query",
        "/v1/scenes/{id}/views/{view}/depth.png",
        "/v1/jobs",
        "/v1/jobs/{id}/events",
        "/ready",
    ] {
        assert!(doc["paths"][path].is_object(), "{path} missing from the OpenAPI document");
    }
    for form in ["ReconstructForm", "JobForm"] {
        assert_eq!(
            doc["components"]["schemas"][form]["properties"]["refine_steps"]["maximum"], 1000,
            "{form}"
        );
    }
    assert!(server.get("/docs").text().contains("/openapi.json"));

    // A request may ask for test-time refinement; the answer says how the photos' fit moved.
    let refined = reconstruct(&server, &photos[..2], ("refine_steps", b"15"));
    let fit = refined.refinement.expect("refinement asked for");
    assert_eq!(fit.steps, 15);
    assert!(fit.input_psnr_after > fit.input_psnr_before, "{fit:?}");
    assert_eq!(fit.photo_gains.len(), 2, "{fit:?}");
    assert!(fit.photo_gains.iter().all(|g| (0.5..2.0).contains(g)), "{fit:?}");
    assert!(
        refined.timings.iter().any(|t| t.stage == "refine" && t.ms > 0.0),
        "{:?}",
        refined.timings
    );
}

/// Follows a job's events until it ends; returns the states seen and the final status.
fn follow(server: &Server, job: &str) -> (Vec<JobState>, JobStatus) {
    let mut statuses = server.follow_job(job);
    let seen = statuses.iter().map(|s| s.state).collect();
    (seen, statuses.pop().expect("at least one event"))
}

#[test]
fn batch_jobs_score_dataset_scenes_stream_progress_and_cancel() {
    let dir = tempfile::tempdir().unwrap();
    let model = support::tiny_model(dir.path());
    let data = dir.path().join("scenes");
    let gt: Vec<_> = (0..2).map(|i| support::test_scene(&data, i)).collect();
    let mut server = Server::start(&model, &dir.path().join("data"), &[]);

    // A tar of two dataset scenes (with eval splits): reconstructed and scored.
    let tar_bytes = inssplat_e2e::tar_of(&data, &["."]);
    let r = server.send("POST", "/v1/jobs", &[("Content-Type", "application/x-tar")], &tar_bytes);
    assert_eq!(r.status, 202, "{}", r.text());
    let job: JobAccepted = r.json();
    assert_eq!(job.scenes, ["scene_000000", "scene_000001"]);
    assert_eq!(r.header("location"), Some(format!("/v1/jobs/{}", job.job_id).as_str()));
    let (seen, status) = follow(&server, &job.job_id);
    assert_eq!(status.state, JobState::Done, "{status:?}");
    assert_eq!(seen.last(), Some(&JobState::Done));
    assert_eq!((status.done, status.total), (2, 2));
    for s in &status.scenes {
        assert_eq!(s.state, JobState::Done, "{s:?}");
        let m = s.metrics.as_ref().expect("ground truth gives metrics");
        for key in ["instance_miou", "instance_pq", "semantic_miou", "psnr", "t_miou"] {
            assert!(m[key].is_number(), "{key} in {m}");
        }
        let ply = server.get(&format!("/v1/scenes/{}/scene.ply", s.scene_id.as_ref().unwrap()));
        assert_eq!(ply.status, 200);
    }
    assert_eq!(server.job(&job.job_id), status);
    assert!(
        status.scenes[0].metrics.as_ref().unwrap()["refine_context_psnr"].is_null(),
        "refined unasked"
    );

    // The same archive as a multipart part, with refinement: the scores say how the fit moved.
    let (ct, body) =
        multipart(&[("archive", Some("scenes.tar"), &tar_bytes), ("refine_steps", None, b"6")]);
    let r = server.send("POST", "/v1/jobs", &[("Content-Type", &ct)], &body);
    assert_eq!(r.status, 202, "{}", r.text());
    let (_, refined) = follow(&server, &r.json::<JobAccepted>().job_id);
    for s in &refined.scenes {
        let psnr = &s.metrics.as_ref().expect("ground truth gives metrics")["refine_context_psnr"];
        assert!(psnr[1].as_f64().unwrap() > psnr[0].as_f64().unwrap(), "{}: {psnr}", s.name);
    }

    // Photo sets as multipart, one of them unusable: that scene fails, the job still ends done.
    let photos = scene_photos(&gt[0]);
    let junk = png(8, 8, 1);
    let mut parts: Vec<(&str, Option<&str>, &[u8])> =
        photos.iter().take(3).map(|p| ("room-a", Some("a.png"), p.as_slice())).collect();
    parts.extend([
        ("room-b", Some("b.png"), junk.as_slice()),
        ("room-b", Some("c.png"), &junk[..junk.len() - 20]),
    ]);
    let (ct, body) = multipart(&parts);
    let r = server.send("POST", "/v1/jobs", &[("Content-Type", &ct)], &body);
    assert_eq!(r.status, 202, "{}", r.text());
    let job: JobAccepted = r.json();
    let (_, status) = follow(&server, &job.job_id);
    assert_eq!(status.state, JobState::Done, "{status:?}");
    assert_eq!(status.scenes[0].state, JobState::Done);
    assert!(status.scenes[0].metrics.is_none(), "photos carry no ground truth");
    assert_eq!(status.scenes[1].state, JobState::Failed);
    assert!(
        status.scenes[1].error.as_deref().unwrap().contains("c.png"),
        "{:?}",
        status.scenes[1].error
    );

    // Cancelling: queued scenes never run.
    let mut parts: Vec<(&str, Option<&str>, &[u8])> = Vec::new();
    let names: Vec<String> = (0..12).map(|i| format!("s{i}")).collect();
    for n in &names {
        parts.extend(photos.iter().take(2).map(|p| (n.as_str(), Some("p.png"), p.as_slice())));
    }
    let (ct, body) = multipart(&parts);
    let job: JobAccepted = server.send("POST", "/v1/jobs", &[("Content-Type", &ct)], &body).json();
    let cancelled: JobStatus =
        server.send("DELETE", &format!("/v1/jobs/{}", job.job_id), &[], b"").json();
    assert_eq!(cancelled.state, JobState::Cancelled);
    std::thread::sleep(Duration::from_millis(300));
    let later = server.job(&job.job_id);
    let ran = later
        .scenes
        .iter()
        .filter(|s| matches!(s.state, JobState::Done | JobState::Failed))
        .count();
    assert!(ran <= 1, "at most the scene running at cancel time finishes: {later:?}");
    assert!(later.scenes.iter().filter(|s| s.state == JobState::Cancelled).count() >= 11);
    let metrics = server.get("/metrics").text();
    assert!(
        metrics.contains("inssplat_jobs{state=\"done\"} 3")
            && metrics.contains("inssplat_jobs{state=\"cancelled\"} 1"),
        "{metrics}"
    );
    // The 6 scenes of the first three jobs were claimed and recorded, each timed.
    for call in ["claim", "finish"] {
        let key = format!("inssplat_job_store_duration_seconds_count{{call=\"{call}\"}} ");
        let line = metrics.lines().find(|l| l.starts_with(&key)).expect(&key);
        assert!(line[key.len()..].parse::<u64>().unwrap() >= 6, "{line}");
    }

    let code = server.terminate(Duration::from_secs(30));
    assert!(code.success(), "SIGTERM ends the service cleanly: {code:?}\n{}", server.log_text());
}

/// `serve --no-ray-pass` answers with the first pass of a network that reads its cameras.
#[test]
fn a_server_told_so_runs_the_network_once() {
    let dir = tempfile::tempdir().unwrap();
    let scene = support::test_scene(dir.path(), 3);
    let server = Server::start(&shipped_model(), &dir.path().join("data"), &["--no-ray-pass"]);
    let rec = reconstruct(&server, &scene_photos(&scene)[..2], ("vocab", b"chair"));
    assert!(
        rec.timings.iter().any(|t| t.stage == "model")
            && rec.timings.iter().all(|t| t.stage != "rays"),
        "{:?}",
        rec.timings
    );
}
