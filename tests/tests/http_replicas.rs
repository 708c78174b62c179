//! Several replicas: three `inssplat serve` sharing one PostgreSQL job store (a real server
//! started on loopback) and one data directory. A job of 24 dataset scenes (the tiny network;
//! ground truth, so every scene is scored) submitted to one replica is run by all of them,
//! through one replica killed with SIGKILL mid-scene (its claim runs out and another replica
//! runs the scene again under its id) and another restarted, or through a restart of
//! PostgreSQL itself. Either way every scene is recorded exactly once, with the scores and the
//! PLY that one replica alone makes, every replica serves every result, and a client following
//! the job's events on another replica sees it end. The nginx configuration that
//! `docker/compose.yaml` puts in front of two replicas is run too (Debian's nginx, its upstreams
//! pointed at two replicas on loopback): a job sent through it is run by both and followed
//! through it as it goes, and a job sent to one replica is cancelled through the other.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use crate::support::http::{Client, Server};
use crate::support::{test_scene, tiny_model};
use inssplat_e2e::postgres::TestPostgres;
use inssplat_proto::api::{JobAccepted, JobState, JobStatus};

const SCENES: usize = 24;
/// Claims last 3 s here (30 by default), so a killed replica's scene is free soon.
const LEASE_S: &str = "3";
const LIMIT: Duration = Duration::from_secs(240);

/// The network, the job (a tar of the scenes) and what one replica alone makes of it.
struct Fixture {
    dir: tempfile::TempDir,
    model: PathBuf,
    tar: Vec<u8>,
    /// Per scene: its scores and its PLY.
    reference: Vec<(serde_json::Value, Vec<u8>)>,
}

fn fixture() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let scenes = dir.path().join("scenes");
    for i in 0..SCENES as u64 {
        // Scored on 4 views (not 16) to keep the test short.
        let transforms = test_scene(&scenes, i).join("transforms.json");
        let mut t: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&transforms).unwrap()).unwrap();
        t["eval"]["context"].as_object_mut().unwrap().retain(|views, _| views == "4");
        std::fs::write(&transforms, serde_json::to_vec(&t).unwrap()).unwrap();
    }
    let tar = inssplat_e2e::tar_of(&scenes, &["."]);
    // One replica alone, on SQLite.
    let alone = Server::start(&model, &dir.path().join("alone"), &[]);
    let job = submit(&alone, &tar);
    let status = wait_end(&[&alone], &job);
    let reference = status
        .scenes
        .iter()
        .map(|s| {
            let ply = alone.get(&format!("/v1/scenes/{}/scene.ply", s.scene_id.as_ref().unwrap()));
            assert_eq!(ply.status, 200);
            (scores(s.metrics.as_ref().expect("ground truth gives scores")), ply.body)
        })
        .collect();
    Fixture { dir, model, tar, reference }
}

impl Fixture {
    /// A replica on `listen` (`127.0.0.1:0`: a new one) of the job store at `url`.
    fn replica(&self, listen: &str, url: &str) -> Server {
        let data = self.dir.path().join("shared");
        Server::start_on(listen, &self.model, &data, &["--jobs", url, "--job-lease-s", LEASE_S])
    }

    /// Every scene done once, scored and stored as by one replica alone, and served by each
    /// of `replicas`.
    fn check(&self, status: &JobStatus, replicas: &[&Server]) {
        assert_eq!(status.state, JobState::Done, "{status:?}");
        assert_eq!((status.done, status.total), (SCENES, SCENES));
        for (s, (want, ply)) in status.scenes.iter().zip(&self.reference) {
            assert_eq!(s.state, JobState::Done, "{s:?}");
            let got = scores(s.metrics.as_ref().expect("scored"));
            assert_eq!(&got, want, "scene {}: not the scores of one replica alone", s.name);
            let id = s.scene_id.as_ref().unwrap();
            for replica in replicas {
                let got = replica.get(&format!("/v1/scenes/{id}/scene.ply"));
                assert_eq!(got.status, 200, "{} does not serve scene {}", replica.addr, s.name);
                assert!(got.body == *ply, "scene {}: not the PLY of one replica alone", s.name);
            }
        }
        let mut ids: Vec<&String> =
            status.scenes.iter().filter_map(|s| s.scene_id.as_ref()).collect();
        ids.sort();
        ids.dedup();
        let stored = std::fs::read_dir(self.dir.path().join("shared/scenes"))
            .unwrap()
            .filter(|e| !e.as_ref().unwrap().file_name().to_string_lossy().starts_with('.'))
            .count();
        assert_eq!((ids.len(), stored), (SCENES, SCENES), "one stored scene per scene");
    }
}

/// A scene's scores without its timings.
fn scores(metrics: &serde_json::Value) -> serde_json::Value {
    let mut scores = metrics.clone();
    let fields = scores.as_object_mut().unwrap();
    assert!(fields.remove("seconds").is_some() && fields.remove("stage_ms").is_some());
    assert_eq!(fields["views"], 4);
    scores
}

fn submit(server: &Client, tar: &[u8]) -> String {
    let r = server.send("POST", "/v1/jobs", &[("Content-Type", "application/x-tar")], tar);
    assert_eq!(r.status, 202, "{}", r.text());
    let job: JobAccepted = r.json();
    assert_eq!(job.scenes.len(), SCENES);
    job.job_id
}

/// Waits on the first of `servers` until the job has `n` scenes finished.
fn wait_done(servers: &[&Server], job: &str, n: usize) -> JobStatus {
    servers[0]
        .wait_job(job, n, LIMIT)
        .unwrap_or_else(|s| panic!("{} of {n} scenes done: {s:?}\n{}", s.done, logs(servers)))
}

fn wait_end(servers: &[&Server], job: &str) -> JobStatus {
    wait_done(servers, job, SCENES)
}

fn logs(servers: &[&Server]) -> String {
    servers.iter().map(|s| format!("--- {}\n{}", s.addr, s.log_text())).collect()
}

/// Indices of the scenes of `job` that `log` says reached `what` ("started", "done").
fn scenes_in(log: &str, job: &str, what: &str) -> Vec<usize> {
    let prefix = format!("job {job} scene ");
    log.lines()
        .filter_map(|l| {
            let rest = &l[l.find(&prefix)? + prefix.len()..];
            let (index, tail) = rest.split_once(' ')?;
            tail.ends_with(&format!("): {what}")).then(|| index.parse().unwrap())
        })
        .collect()
}

#[test]
fn three_replicas_run_a_job_through_a_kill_9_and_a_restart() {
    let f = fixture();
    let postgres = TestPostgres::start();
    let url = postgres.database("jobs");
    let a = f.replica("127.0.0.1:0", &url);
    let mut b = f.replica("127.0.0.1:0", &url);
    let mut c = f.replica("127.0.0.1:0", &url);
    // Submitted to b, which dies; followed on a, which stays.
    let job = submit(&b, &f.tar);
    let events = {
        let (a, job) = (Client::new(a.addr), job.clone());
        std::thread::spawn(move || a.follow_job(&job).pop().unwrap())
    };

    // SIGKILL b while it runs a scene.
    let start = Instant::now();
    let killed = loop {
        let log = b.log_text();
        let done = scenes_in(&log, &job, "done");
        if let Some(&i) = scenes_in(&log, &job, "started").iter().find(|i| !done.contains(i)) {
            break i;
        }
        assert!(start.elapsed() < LIMIT, "b ran no scene\n{}", logs(&[&a, &b, &c]));
        std::thread::sleep(Duration::from_millis(5));
    };
    b.kill9();
    assert!(!scenes_in(&b.log_text(), &job, "done").contains(&killed), "killed after the scene");

    // Restart c (SIGTERM lets its scene finish) where it listened.
    let before = wait_done(&[&a], &job, 8);
    assert!(before.done < SCENES, "the job ended before c could be restarted");
    let listen = c.addr.to_string();
    assert!(c.terminate(LIMIT).success(), "{}", c.log_text());
    let c2 = f.replica(&listen, &url);

    let end = wait_end(&[&a, &c2], &job);
    f.check(&end, &[&a, &c2]);
    assert_eq!(events.join().unwrap(), end, "the events on a end where the job did");
    let ran_again: Vec<usize> = [&a, &c, &c2]
        .iter()
        .flat_map(|s| scenes_in(&s.log_text(), &job, "done"))
        .filter(|&i| i == killed)
        .collect();
    assert_eq!(ran_again, [killed], "another replica ran the killed scene, once");
    let ran: Vec<usize> =
        [&a, &b, &c, &c2].iter().map(|s| scenes_in(&s.log_text(), &job, "done").len()).collect();
    assert_eq!(ran.iter().sum::<usize>(), SCENES, "each scene recorded once: {ran:?}");
    assert!(ran.iter().filter(|&&n| n > 0).count() >= 3, "the replicas shared it: {ran:?}");
}

#[test]
fn replicas_ride_out_a_postgresql_restart() {
    let f = fixture();
    let postgres = TestPostgres::start();
    let url = postgres.database("jobs");
    let replicas: Vec<Server> = (0..3).map(|_| f.replica("127.0.0.1:0", &url)).collect();
    let all: Vec<&Server> = replicas.iter().collect();
    let job = submit(&replicas[1], &f.tar);
    let before = wait_done(&all, &job, 6);
    assert!(before.done < SCENES, "the job ended before PostgreSQL could be restarted");
    postgres.stop();
    std::thread::sleep(Duration::from_secs(2));
    postgres.restart();
    let end = wait_end(&all, &job);
    f.check(&end, &all);
    let text = logs(&all);
    assert!(text.contains("cannot connect to the job store"), "no replica saw the outage\n{text}");
    let ran: usize = all.iter().map(|s| scenes_in(&s.log_text(), &job, "done").len()).sum();
    assert_eq!(ran, SCENES, "each scene recorded once\n{text}");
}

/// nginx with `docker/nginx.conf`, its upstreams `replicas` and its port free on loopback.
struct Proxy {
    child: std::process::Child,
    addr: std::net::SocketAddr,
    _dir: tempfile::TempDir,
}

impl Proxy {
    fn start(replicas: [&Server; 2]) -> Proxy {
        let dir = tempfile::tempdir().unwrap();
        let conf = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docker/nginx.conf"),
        )
        .unwrap();
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap();
        let mut local = conf.clone();
        for (host, replica) in [("replica-a:8080", replicas[0]), ("replica-b:8080", replicas[1])] {
            assert!(local.contains(host), "docker/nginx.conf has no upstream {host}");
            local = local.replace(host, &replica.addr.to_string());
        }
        let listen = format!("listen 127.0.0.1:{};", port.port());
        local = local.replace("listen 8080;", &listen);
        assert!(local.contains(&listen), "docker/nginx.conf does not listen on 8080");
        // Logs and buffers in the test's folder rather than the system's.
        let paths =
            "http {\n  access_log off;\n  client_body_temp_path body;\n  proxy_temp_path proxy;";
        local = local.replacen("http {", paths, 1);
        std::fs::write(dir.path().join("nginx.conf"), local).unwrap();
        let nginx = ["/usr/sbin/nginx", "nginx"]
            .into_iter()
            .find(|n| std::process::Command::new(n).arg("-v").output().is_ok())
            .expect("nginx (Debian's nginx, installed by scripts/setup)");
        let pid = dir.path().join("nginx.pid");
        let child = std::process::Command::new(nginx)
            .arg("-p")
            .arg(dir.path())
            .args(["-c", "nginx.conf", "-e", "stderr", "-g"])
            .arg(format!("daemon off; pid {};", pid.display()))
            .spawn()
            .unwrap();
        let start = Instant::now();
        while std::net::TcpStream::connect(port).is_err() {
            assert!(start.elapsed() < Duration::from_secs(20), "nginx did not start");
            std::thread::sleep(Duration::from_millis(20));
        }
        Proxy { child, addr: port, _dir: dir }
    }
}

impl Drop for Proxy {
    /// SIGTERM, which stops nginx's workers with it (SIGKILL would leave them running).
    fn drop(&mut self) {
        let pid = self.child.id().to_string();
        let _ = std::process::Command::new("kill").args(["-TERM", &pid]).status();
        let _ = self.child.wait();
    }
}

#[test]
fn the_compose_proxy_spreads_a_job_over_two_replicas_and_streams_its_progress() {
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let postgres = TestPostgres::start();
    let url = postgres.database("jobs");
    let data = dir.path().join("shared");
    let args = ["--jobs", url.as_str()];
    let (a, b) = (Server::start(&model, &data, &args), Server::start(&model, &data, &args));
    let proxy = Proxy::start([&a, &b]);
    // The proxy as a client sees it: one address.
    let front = Client::new(proxy.addr);

    let photos: Vec<Vec<u8>> = (0..2).map(|i| crate::support::http::png(64, 48, i)).collect();
    let names: Vec<String> = (0..8).map(|i| format!("room{i}")).collect();
    let parts: Vec<(&str, Option<&str>, &[u8])> = names
        .iter()
        .flat_map(|n| photos.iter().map(move |p| (n.as_str(), Some("p.jpg"), p.as_slice())))
        .collect();
    let (ct, body) = crate::support::http::multipart(&parts);
    let r = front.send("POST", "/v1/jobs", &[("Content-Type", &ct)], &body);
    assert_eq!(r.status, 202, "{}", r.text());
    let job: JobAccepted = r.json();
    let progress: Vec<usize> = front.follow_job(&job.job_id).iter().map(|s| s.done).collect();
    assert_eq!(progress.last(), Some(&names.len()), "{progress:?}");
    assert!(
        progress.iter().any(|&d| 0 < d && d < names.len()),
        "no progress came through the proxy before the end: {progress:?}"
    );
    let end = front.job(&job.job_id);
    assert_eq!(end.state, JobState::Done, "{end:?}");
    for s in &end.scenes {
        let ply = front.get(&format!("/v1/scenes/{}/scene.ply", s.scene_id.as_ref().unwrap()));
        assert_eq!(ply.status, 200, "{}", s.name);
    }
    let ran: Vec<usize> =
        [&a, &b].iter().map(|s| scenes_in(&s.log_text(), &job.job_id, "done").len()).collect();
    assert_eq!(ran.iter().sum::<usize>(), names.len(), "{ran:?}");
    assert!(ran.iter().all(|&n| n > 0), "both replicas ran scenes: {ran:?}");

    // A job sent to a is cancelled through b: its queued scenes never run on either.
    let r = a.send("POST", "/v1/jobs", &[("Content-Type", &ct)], &body);
    let job: JobAccepted = r.json();
    let cancelled: JobStatus =
        b.send("DELETE", &format!("/v1/jobs/{}", job.job_id), &[], b"").json();
    assert_eq!(cancelled.state, JobState::Cancelled, "{cancelled:?}");
    std::thread::sleep(Duration::from_millis(500));
    let later = a.job(&job.job_id);
    assert_eq!(later.state, JobState::Cancelled, "{later:?}");
    let ran = later.scenes.iter().filter(|s| s.state != JobState::Cancelled).count();
    assert!(ran <= 2, "at most the scene each replica was running goes on: {later:?}");
}
