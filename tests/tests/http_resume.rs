//! Durable jobs: a 10-scene job on the real service (shipped network; the job store a real
//! SQLite file, or a real PostgreSQL server with `--jobs`) is interrupted twice, first by
//! `kill -9` mid-scene, then by SIGTERM (which lets the running scene finish); after each
//! restart on the same data directory the job resumes, and it ends with exactly 10 results:
//! none lost, none run into a second scene folder. A job store `serve` cannot use is refused
//! at start, by name.

use std::time::Duration;

use crate::support::http::{Server, multipart, png};
use inssplat_e2e::postgres::TestPostgres;
use inssplat_proto::api::{JobAccepted, JobState, JobStatus};

const SCENES: usize = 10;

/// Waits until at least `n` scenes have finished; returns that status.
fn wait_done(server: &Server, job: &str, n: usize, limit: Duration) -> JobStatus {
    server.wait_job(job, n, limit).unwrap_or_else(|s| {
        panic!("{} of {n} scenes after {limit:?}: {s:?}\n{}", s.done, server.log_text())
    })
}

#[test]
fn a_job_survives_kill_9_and_sigterm_with_every_result_once() {
    survives_kill_9_and_sigterm(&[]);
}

#[test]
fn a_job_on_postgresql_survives_kill_9_and_sigterm_with_every_result_once() {
    let postgres = TestPostgres::start();
    survives_kill_9_and_sigterm(&["--jobs", &postgres.database("jobs")]);
}

/// The job's run through both interruptions, the server started with `args`.
fn survives_kill_9_and_sigterm(args: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let model =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx");
    let data = dir.path().join("data");
    let mut server = Server::start(&model, &data, args);

    let photos: Vec<Vec<u8>> = (0..8).map(|i| png(160, 120, i)).collect();
    let names: Vec<String> = (0..SCENES).map(|i| format!("scene{i:02}")).collect();
    let parts: Vec<(&str, Option<&str>, &[u8])> = names
        .iter()
        .flat_map(|n| photos.iter().map(move |p| (n.as_str(), Some("p.png"), p.as_slice())))
        .collect();
    let (ct, body) = multipart(&parts);
    let r = server.send("POST", "/v1/jobs", &[("Content-Type", &ct)], &body);
    assert_eq!(r.status, 202, "{}", r.text());
    let job: JobAccepted = r.json();
    assert_eq!(job.scenes, names);

    // kill -9 while a scene runs.
    let before = wait_done(&server, &job.job_id, 2, Duration::from_secs(60));
    assert!(before.done < SCENES, "the job finished before it could be killed: {before:?}");
    let running: Vec<(usize, String)> = before
        .scenes
        .iter()
        .filter(|s| s.state == JobState::Running)
        .map(|s| (s.index, s.scene_id.clone().unwrap()))
        .collect();
    let listen = server.addr.to_string();
    server.kill9();

    // Started again where it listened: the same replica, which takes its scenes back at once.
    let server = Server::start_on(&listen, &model, &data, args);
    assert!(
        server.log_text().contains("queued again") || running.is_empty(),
        "{}",
        server.log_text()
    );
    let mid = wait_done(&server, &job.job_id, before.done + 2, Duration::from_secs(60));
    for (index, id) in &running {
        assert_eq!(
            mid.scenes[*index].scene_id.as_ref(),
            Some(id),
            "an interrupted scene keeps its scene id"
        );
    }
    // SIGTERM: the running scene finishes, the rest waits in the store.
    let mut server = server;
    let code = server.terminate(Duration::from_secs(60));
    assert!(code.success(), "{code:?}\n{}", server.log_text());
    assert!(server.log_text().contains("stopped"), "{}", server.log_text());

    let server = Server::start_on(&listen, &model, &data, args);
    let end = wait_done(&server, &job.job_id, SCENES, Duration::from_secs(90));
    assert_eq!(end.state, JobState::Done, "{end:?}");
    assert_eq!((end.done, end.total), (SCENES, SCENES));
    let mut ids: Vec<String> = end.scenes.iter().map(|s| s.scene_id.clone().unwrap()).collect();
    assert!(end.scenes.iter().all(|s| s.state == JobState::Done && s.error.is_none()), "{end:?}");
    for id in &ids {
        assert_eq!(server.get(&format!("/v1/scenes/{id}/scene.ply")).status, 200);
    }
    ids.sort();
    ids.dedup();
    assert_eq!(ids.len(), SCENES, "one scene id per scene");
    let mut folders: Vec<String> = std::fs::read_dir(data.join("scenes"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| !name.starts_with('.'))
        .collect();
    folders.sort();
    assert_eq!(folders, ids, "exactly the 10 results are stored");
    for replica in std::fs::read_dir(data.join("scenes/.staging")).unwrap() {
        let left: Vec<_> = std::fs::read_dir(replica.unwrap().path()).unwrap().collect();
        assert!(left.is_empty(), "staged scenes left behind: {left:?}");
    }
}

#[test]
fn serve_refuses_a_job_store_it_cannot_use_and_names_it_without_the_password() {
    let dir = tempfile::tempdir().unwrap();
    let serve = |url: &str| {
        let out = std::process::Command::new(inssplat_e2e::inssplat_bin())
            .args(["serve", "--listen", "127.0.0.1:0", "--jobs", url, "--data-dir"])
            .arg(dir.path())
            .output()
            .unwrap();
        assert!(!out.status.success(), "{url} was accepted");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let err = serve("mysql://jobs@db/inssplat");
    assert!(err.contains("--jobs") && err.contains("not a PostgreSQL URL"), "{err}");
    // Port 1 on loopback: nothing listens.
    let err = serve("postgres://jobs:secret@127.0.0.1:1/inssplat");
    assert!(
        err.contains("cannot connect to the job store postgres://jobs:***@127.0.0.1:1"),
        "{err}"
    );
    assert!(!err.contains("secret"), "{err}");
}
