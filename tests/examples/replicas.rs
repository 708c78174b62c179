//! Batch-job throughput on loopback: one job of dataset scenes (scored against their ground
//! truth) run by one replica on SQLite, then by 1, 2 and 3 replicas sharing one PostgreSQL
//! server (started as the tests start it) and one data directory. Prints a Markdown table:
//! scenes per minute, the median time one scene took inside its replica (so where the time
//! goes when replicas share the cores), and the job store's time per scene from the replicas'
//! `/metrics` (claims that found a scene, results, renewals; idle polls apart).
//!
//! ```sh
//! cargo build --release -p inssplat-server --bin inssplat
//! cargo run --release -p inssplat-e2e --example replicas -- target/release/inssplat data/test40 24
//! ```

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use inssplat_e2e::http::Server;
use inssplat_e2e::postgres::TestPostgres;
use inssplat_proto::api::JobAccepted;

const USAGE: &str = "usage: replicas <inssplat binary> <folder of dataset scenes> <scenes>";

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [bin, scenes, count] = args.as_slice() else { return Err(USAGE.into()) };
    let (bin, scenes) = (PathBuf::from(bin), PathBuf::from(scenes));
    let count: usize = count.parse().map_err(|_| format!("<scenes> `{count}`: not a count"))?;
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx");
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let tar = job_tar(&scenes, count)?;
    let postgres = TestPostgres::start();

    println!(
        "| job store | replicas | wall s | scenes/min | one scene, median s | store ms/scene | idle polls ms |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (run, (store, replicas)) in
        [("SQLite", 1), ("PostgreSQL", 1), ("PostgreSQL", 2), ("PostgreSQL", 3)]
            .into_iter()
            .enumerate()
    {
        let url = postgres.database(&format!("run{run}"));
        let args: &[&str] = if store == "SQLite" { &[] } else { &["--jobs", &url] };
        let data = dir.path().join(format!("run{run}"));
        let servers: Vec<Server> = (0..replicas)
            .map(|_| Server::start_binary(&bin, "127.0.0.1:0", &model, &data, args))
            .collect();
        let start = Instant::now();
        let r = servers[0].send("POST", "/v1/jobs", &[("Content-Type", "application/x-tar")], &tar);
        if r.status != 202 {
            return Err(format!("the job was refused: {}", r.text()));
        }
        let job: JobAccepted = r.json();
        let status = servers[0]
            .wait_job(&job.job_id, count, Duration::from_secs(3600))
            .map_err(|s| format!("not done within an hour: {s:?}"))?;
        let wall = start.elapsed().as_secs_f64();
        let mut seconds: Vec<f64> =
            status.scenes.iter().filter_map(|s| s.metrics.as_ref()?["seconds"].as_f64()).collect();
        if seconds.len() != count {
            return Err(format!("{} of {count} scenes were scored: {status:?}", seconds.len()));
        }
        seconds.sort_by(f64::total_cmp);
        let metrics: Vec<String> = servers.iter().map(|s| s.get("/metrics").text()).collect();
        let store_s = |calls: &[&str]| -> f64 {
            metrics.iter().flat_map(|m| calls.iter().map(move |c| store_sum(m, c))).sum()
        };
        println!(
            "| {store} | {replicas} | {wall:.1} | {:.1} | {:.2} | {:.2} | {:.1} |",
            count as f64 * 60.0 / wall,
            seconds[count / 2],
            store_s(&["claim", "finish", "renew"]) * 1e3 / count as f64,
            store_s(&["poll"]) * 1e3,
        );
    }
    Ok(())
}

/// The first `count` scenes under `scenes` as one tar.
fn job_tar(scenes: &Path, count: usize) -> Result<Vec<u8>, String> {
    let mut names: Vec<String> = std::fs::read_dir(scenes)
        .map_err(|e| format!("{}: {e}", scenes.display()))?
        .flatten()
        .filter(|e| e.path().join("transforms.json").is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    if names.len() < count {
        return Err(format!("{}: {} dataset scenes, not {count}", scenes.display(), names.len()));
    }
    let entries: Vec<&str> = names[..count].iter().map(String::as_str).collect();
    Ok(inssplat_e2e::tar_of(scenes, &entries))
}

/// Seconds the job store's `call` took in all, from a `/metrics` text.
fn store_sum(metrics: &str, call: &str) -> f64 {
    let key = format!("inssplat_job_store_duration_seconds_sum{{call=\"{call}\"}} ");
    metrics.lines().find_map(|l| l.strip_prefix(&key)).map_or(0.0, |v| v.parse().unwrap_or(0.0))
}
