//! The service at about 4× its capacity (20 clients in a closed loop against one worker and a
//! queue of 4, shipped network, real binary): the excess is answered 429 with Retry-After,
//! nothing answers 5xx, resident memory stays bounded, and requests whose client has gone are
//! dropped before they cost compute. Prints the accepted requests' p50/p99 latency.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::support::http::{Server, multipart, percentile, png};

const CLIENTS: usize = 20;
const QUEUE: usize = 4;
const LOAD: Duration = Duration::from_secs(6);

#[test]
fn overload_is_answered_429_without_errors_or_memory_growth() {
    let dir = tempfile::tempdir().unwrap();
    let model =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx");
    let server = Arc::new(Server::start(
        &model,
        &dir.path().join("data"),
        &["--queue", &QUEUE.to_string(), "--workers", "1"],
    ));
    let photos: Vec<Vec<u8>> = (0..4).map(|i| png(160, 120, i)).collect();
    let parts: Vec<(&str, Option<&str>, &[u8])> =
        photos.iter().map(|p| ("images", Some("p.png"), p.as_slice())).collect();
    let (ct, body) = multipart(&parts);
    let request = Arc::new((ct, body));
    // Warm up (first-use allocations), then measure.
    for _ in 0..3 {
        assert_eq!(
            server
                .send("POST", "/v1/reconstruct", &[("Content-Type", &request.0)], &request.1)
                .status,
            200
        );
    }
    let rss_before = server.rss_kib();

    let start = Instant::now();
    let clients: Vec<_> = (0..CLIENTS)
        .map(|_| {
            let (server, request) = (server.clone(), request.clone());
            std::thread::spawn(move || {
                let mut seen = Vec::new();
                while start.elapsed() < LOAD {
                    let t = Instant::now();
                    let r = server.send(
                        "POST",
                        "/v1/reconstruct",
                        &[("Content-Type", &request.0)],
                        &request.1,
                    );
                    seen.push((
                        r.status,
                        t.elapsed(),
                        r.header("retry-after").map(str::to_string),
                        r.body.clone(),
                    ));
                    if r.status == 429 {
                        std::thread::sleep(Duration::from_millis(100));
                    }
                }
                seen
            })
        })
        .collect();
    let results: Vec<_> = clients.into_iter().flat_map(|c| c.join().unwrap()).collect();
    let rss_after = server.rss_kib();

    let accepted: Vec<Duration> = results.iter().filter(|r| r.0 == 200).map(|r| r.1).collect();
    let rejected: Vec<_> = results.iter().filter(|r| r.0 == 429).collect();
    let other: Vec<_> = results
        .iter()
        .filter(|r| r.0 != 200 && r.0 != 429)
        .map(|r| (r.0, String::from_utf8_lossy(&r.3).into_owned()))
        .collect();
    assert!(other.is_empty(), "only 200 and 429 expected: {other:?}");
    assert!(
        !accepted.is_empty() && !rejected.is_empty(),
        "{} accepted, {} rejected",
        accepted.len(),
        rejected.len()
    );
    for r in &rejected {
        let secs: u64 = r.2.as_deref().expect("429 carries Retry-After").parse().unwrap();
        assert!(secs >= 1);
        let e: inssplat_proto::api::ErrorBody = serde_json::from_slice(&r.3).unwrap();
        assert_eq!(e.error_type, "overloaded");
    }
    let (p50, p99) = (percentile(&accepted, 50.0), percentile(&accepted, 99.0));
    println!(
        "load: {CLIENTS} clients for {LOAD:?} against 1 worker + queue {QUEUE}: {} accepted ({:.1}/s), {} answered 429; accepted p50 {p50:?}, p99 {p99:?}; RSS {} → {} MiB",
        accepted.len(),
        accepted.len() as f64 / LOAD.as_secs_f64(),
        rejected.len(),
        rss_before / 1024,
        rss_after / 1024,
    );
    assert!(
        rss_after < rss_before + 200 * 1024,
        "RSS grew from {rss_before} KiB to {rss_after} KiB"
    );
    // A waiting request never waits longer than the queue ahead of it takes.
    assert!(p99 < Duration::from_secs(30), "p99 {p99:?}");

    // Clients that give up while queued cost nothing: their tasks are dropped unrun.
    let runs_before = stage_count(&server);
    let quitters: Vec<_> = (0..QUEUE + 1)
        .map(|_| {
            let (server, request) = (server.clone(), request.clone());
            std::thread::spawn(move || {
                let mut s = std::net::TcpStream::connect(server.addr).unwrap();
                let head = format!("POST /v1/reconstruct HTTP/1.1\r\nHost: x\r\nContent-Type: {}\r\nContent-Length: {}\r\n\r\n", request.0, request.1.len());
                std::io::Write::write_all(&mut s, head.as_bytes()).unwrap();
                std::io::Write::write_all(&mut s, &request.1).unwrap();
                std::thread::sleep(Duration::from_millis(30));
                drop(s);
            })
        })
        .collect();
    quitters.into_iter().for_each(|q| q.join().unwrap());
    std::thread::sleep(Duration::from_secs(2));
    let metrics = server.get("/metrics").text();
    let dropped: u64 = metric(&metrics, "inssplat_tasks_dropped_total ");
    let ran = stage_count(&server) - runs_before;
    assert!(
        dropped >= 1 && ran < (QUEUE + 1) as u64,
        "dropped {dropped}, ran {ran} of {}\n{metrics}",
        QUEUE + 1
    );
    assert_eq!(server.get("/ready").status, 200);
}

fn metric(text: &str, prefix: &str) -> u64 {
    text.lines()
        .find_map(|l| l.strip_prefix(prefix))
        .and_then(|v| v.trim().parse::<f64>().ok())
        .unwrap_or(0.0) as u64
}

/// Pipeline runs so far (the model stage's count).
fn stage_count(server: &Server) -> u64 {
    metric(
        &server.get("/metrics").text(),
        "inssplat_stage_duration_seconds_count{stage=\"model\"} ",
    )
}
