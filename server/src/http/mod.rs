//! `inssplat serve`: the axum HTTP service in front of the pipeline. Routes live in one
//! module per resource (`reconstruct`, `scenes`, `jobs`, `ops`, and `page` for the web page);
//! `layers` holds the API key
//! check, the request timeout and the access log/metrics; `error` the one error shape. The
//! model itself runs on the `worker` threads; the service binds first (printing its address,
//! so port 0 works), answers `/health` at once and `/ready` once the model is warm.

mod archive;
mod error;
mod jobs;
mod layers;
mod openapi;
mod ops;
mod page;
mod reconstruct;
mod scenes;
mod upload;

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use axum::Router;
use axum::extract::DefaultBodyLimit;
use axum::middleware::from_fn_with_state;
use axum::routing::{get, post};
use tokio::sync::{broadcast, watch};

pub use error::ApiError;

use crate::jobs::JobStore;
use crate::metrics::Metrics;
use crate::scene_store::SceneStore;
use crate::worker::{Pool, Shared, WorkerConfig};
use inssplat_pipeline::reconstruct::PipelineConfig;
use inssplat_pipeline::switches::PipelineSwitches;

/// Settings of `inssplat serve`; every flag can also be set by its environment variable.
#[derive(clap::Args)]
pub struct ServeArgs {
    /// Address to listen on; port 0 picks a free port (the bound address is printed).
    #[arg(long, env = "INSSPLAT_LISTEN", default_value = "127.0.0.1:8080")]
    pub listen: SocketAddr,
    /// The network (ONNX file exported by inssplat-train).
    #[arg(long, env = "INSSPLAT_MODEL", default_value = "models/inssplat-default.onnx")]
    pub model: PathBuf,
    /// Folder for the job store (jobs.sqlite), job inputs and stored scenes. Replicas sharing
    /// a PostgreSQL job store share this folder too (a volume every replica mounts), so each
    /// serves the scenes the others made.
    #[arg(long, env = "INSSPLAT_DATA_DIR", default_value = "inssplat-data")]
    pub data_dir: PathBuf,
    /// Keep the batch jobs in this PostgreSQL database (`postgres://user:password@host/db`),
    /// which several replicas can share, instead of jobs.sqlite in the data directory. Each
    /// replica claims scenes in the name of its host and bound address, so replicas on one
    /// host need their own ports.
    #[arg(long, env = "INSSPLAT_JOBS_URL", value_name = "URL", value_parser = jobs_url)]
    pub jobs: Option<String>,
    /// Seconds a replica's claim on a job scene holds on PostgreSQL; the replica renews it every
    /// third of that while the scene runs, so a replica that dies frees its scene within it.
    #[arg(long, env = "INSSPLAT_JOB_LEASE_S", default_value_t = 30, value_parser = clap::value_parser!(u64).range(3..))]
    pub job_lease_s: u64,
    /// Model worker threads (each loads its own copy of the network).
    #[arg(long, env = "INSSPLAT_WORKERS", default_value_t = 1)]
    pub workers: usize,
    /// ONNX Runtime threads per worker (default: all cores divided among the workers).
    #[arg(long, env = "INSSPLAT_THREADS")]
    pub threads: Option<usize>,
    /// Requests that may wait for a worker; beyond that the service answers 429.
    #[arg(long, env = "INSSPLAT_QUEUE", default_value_t = 8)]
    pub queue: usize,
    /// Largest request body, MiB (larger ones get 413).
    #[arg(long, env = "INSSPLAT_MAX_BODY_MB", default_value_t = 64)]
    pub max_body_mb: u64,
    /// Seconds a request may take before it is answered 504.
    #[arg(long, env = "INSSPLAT_REQUEST_TIMEOUT_S", default_value_t = 120)]
    pub request_timeout_s: u64,
    /// Bytes the stored scenes may take, MiB; the least recently used go first.
    #[arg(long, env = "INSSPLAT_SCENE_QUOTA_MB", default_value_t = 2048)]
    pub scene_quota_mb: u64,
    /// Hours a stored scene is kept after its last use (0: until the quota needs room).
    #[arg(long, env = "INSSPLAT_SCENE_TTL_H", default_value_t = 24)]
    pub scene_ttl_h: u64,
    /// Default label vocabulary (file or comma-separated list) for requests that send none.
    #[arg(long, env = "INSSPLAT_VOCAB")]
    pub vocab: Option<String>,
    #[command(flatten)]
    pub pipeline: PipelineSwitches,
    /// Require `Authorization: Bearer <key>` on /v1 routes (the key is never logged).
    #[arg(long, env = "INSSPLAT_API_KEY", hide_env_values = true)]
    pub api_key: Option<String>,
    /// The web page's npm packages (three.js, Spark, redoc): the node_modules folder that
    /// scripts/setup installs.
    #[arg(long, env = "INSSPLAT_WEB_DIR", default_value = ".deps/web/node_modules")]
    pub web_dir: PathBuf,
}

/// What every handler can reach.
pub(crate) struct AppState {
    pool: Arc<Pool>,
    shared: Arc<Shared>,
    api_key: Option<String>,
    data_dir: PathBuf,
    /// The page's npm packages (`--web-dir`).
    web_dir: PathBuf,
    default_vocab: Vec<String>,
    max_body_bytes: usize,
    request_timeout: Duration,
    /// Turns true when the service starts shutting down (ends event streams).
    shutdown: watch::Receiver<bool>,
}

/// Runs the service until SIGTERM or Ctrl-C.
pub fn serve(args: ServeArgs) -> anyhow::Result<()> {
    tracing_subscriber::fmt().with_writer(std::io::stderr).with_target(false).init();
    anyhow::ensure!(args.workers >= 1, "--workers must be at least 1");
    anyhow::ensure!(args.queue >= 1, "--queue must be at least 1");
    std::fs::create_dir_all(&args.data_dir)
        .with_context(|| format!("--data-dir {}: cannot create it", args.data_dir.display()))?;
    // Bound first, so the replica's name has the port that port 0 picked.
    let listener = std::net::TcpListener::bind(args.listen)
        .with_context(|| format!("--listen {}: cannot bind", args.listen))?;
    let addr = listener.local_addr()?;
    // The PostgreSQL client blocks: the store opens before the async runtime starts. Replicas
    // sharing it claim scenes (and stage them) in the name of their host and address.
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    let replica = format!("{}:{addr}", host.trim());
    let lease = Duration::from_secs(args.job_lease_s);
    let jobs = crate::jobs::open(args.jobs.as_deref(), &replica, lease, &args.data_dir)?;
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?
        .block_on(run(args, listener, &replica, jobs))
}

/// `--jobs`: a PostgreSQL URL.
fn jobs_url(url: &str) -> Result<String, String> {
    if url.starts_with("postgres://") || url.starts_with("postgresql://") {
        Ok(url.to_string())
    } else {
        Err(format!("`{url}` is not a PostgreSQL URL (postgres://user:password@host/database)"))
    }
}

async fn run(
    args: ServeArgs,
    listener: std::net::TcpListener,
    replica: &str,
    jobs: Arc<dyn JobStore>,
) -> anyhow::Result<()> {
    let expiry = (args.scene_ttl_h > 0).then(|| Duration::from_secs(args.scene_ttl_h * 3600));
    let scenes = SceneStore::open(
        &args.data_dir.join("scenes"),
        replica,
        args.scene_quota_mb << 20,
        expiry,
    )?;
    let store = jobs.clone();
    let requeued = tokio::task::spawn_blocking(move || store.requeue_interrupted()).await??;
    if requeued > 0 {
        tracing::info!("{requeued} job scene(s) interrupted by the last stop are queued again");
    }
    let default_vocab = inssplat_pipeline::vocab::vocabulary(args.vocab.as_deref())?;
    let (job_events, _) = broadcast::channel(256);
    let shared =
        Arc::new(Shared { scenes, jobs, metrics: Arc::new(Metrics::default()), job_events });
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    let threads = args.threads.unwrap_or((cores / args.workers).max(1));
    let pipeline = args.pipeline.apply(PipelineConfig::default(), &args.model, threads)?;
    let config = WorkerConfig {
        model: args.model.clone(),
        threads,
        workers: args.workers,
        queue: args.queue,
        pipeline,
    };
    let (pool, startup) = Pool::start(config, shared.clone());
    let (stop_tx, shutdown) = watch::channel(false);
    let state = Arc::new(AppState {
        pool: pool.clone(),
        shared: shared.clone(),
        api_key: args.api_key.clone().filter(|k| !k.is_empty()),
        data_dir: args.data_dir.clone(),
        web_dir: args.web_dir.clone(),
        default_vocab,
        max_body_bytes: usize::try_from(args.max_body_mb << 20).unwrap_or(usize::MAX),
        request_timeout: Duration::from_secs(args.request_timeout_s.max(1)),
        shutdown,
    });

    if let Some(missing) = page::missing_vendor(&args.web_dir) {
        tracing::warn!("the web page will not work: {missing}");
    }

    listener.set_nonblocking(true)?;
    let listener = tokio::net::TcpListener::from_std(listener)?;
    let addr = listener.local_addr()?;
    println!("listening on http://{addr}");
    std::io::stdout().flush()?;
    tracing::info!(
        "listening on http://{addr}; model {}, data {}, {} worker(s) × {threads} threads, queue {}, body ≤ {} MiB, timeout {} s, API key {}",
        args.model.display(),
        args.data_dir.display(),
        args.workers,
        args.queue,
        args.max_body_mb,
        args.request_timeout_s,
        if state.api_key.is_some() { "required" } else { "not required" },
    );

    let failed = Arc::new(tokio::sync::Mutex::new(None));
    let stop = Arc::new(tokio::sync::Notify::new());
    tokio::spawn({
        let (failed, stop) = (failed.clone(), stop.clone());
        async move {
            match startup.await {
                Ok(Ok(version)) => tracing::info!("ready: model {version} loaded and warmed up"),
                Ok(Err(e)) => {
                    *failed.lock().await = Some(e);
                    stop.notify_one();
                }
                Err(_) => {
                    *failed.lock().await =
                        Some(anyhow::anyhow!("the model loader stopped without a result"));
                    stop.notify_one();
                }
            }
        }
    });
    tokio::spawn(expire_scenes(shared.clone()));

    axum::serve(listener, router(state))
        .with_graceful_shutdown(async move {
            tokio::select! {
                () = shutdown_signal() => tracing::info!("shutting down: finishing running work"),
                () = stop.notified() => {}
            }
            let _ = stop_tx.send(true);
        })
        .await
        .context("serving HTTP")?;
    tokio::task::spawn_blocking(move || pool.stop()).await.context("stopping the workers")?;
    if let Some(e) = failed.lock().await.take() {
        return Err(e.context("the model could not be loaded"));
    }
    tracing::info!("stopped");
    Ok(())
}

/// Removes expired scenes once a minute (new scenes also evict when they are stored).
async fn expire_scenes(shared: Arc<Shared>) {
    let mut tick = tokio::time::interval(Duration::from_secs(60));
    loop {
        tick.tick().await;
        let shared = shared.clone();
        match tokio::task::spawn_blocking(move || shared.scenes.evict(None)).await {
            Ok(Ok(0)) => {}
            Ok(Ok(n)) => tracing::info!("removed {n} expired scene(s)"),
            Ok(Err(e)) => tracing::warn!("scene expiry: {e:#}"),
            Err(e) => tracing::warn!("scene expiry: {e}"),
        }
    }
}

async fn shutdown_signal() {
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(e) => {
                tracing::warn!("cannot listen for SIGTERM: {e}");
                std::future::pending::<()>().await;
            }
        }
    };
    tokio::select! {
        () = term => {}
        r = tokio::signal::ctrl_c() => if let Err(e) = r { tracing::warn!("cannot listen for Ctrl-C: {e}") },
    }
}

/// Every route with its layers.
fn router(state: Arc<AppState>) -> Router {
    let v1 = Router::new()
        .route("/v1/reconstruct", post(reconstruct::reconstruct))
        .route("/v1/scenes/{id}/scene.ply", get(scenes::ply))
        .route("/v1/scenes/{id}/preview.png", get(scenes::preview))
        .route("/v1/scenes/{id}/archive", get(archive::archive))
        .route("/v1/scenes/{id}/views/{view}/instances.png", get(scenes::instances_png))
        .route("/v1/scenes/{id}/views/{view}/labels.png", get(scenes::labels_png))
        .route("/v1/scenes/{id}/views/{view}/ids.png", get(scenes::ids_png))
        .route("/v1/scenes/{id}/views/{view}/depth.png", get(scenes::depth_png))
        .route("/v1/scenes/{id}/query", post(scenes::query))
        .route("/v1/scenes/{id}/query/{slug}/{file}", get(scenes::query_mask))
        .route("/v1/jobs", post(jobs::submit))
        .route("/v1/jobs/{id}", get(jobs::status).delete(jobs::cancel))
        .route("/v1/jobs/{id}/events", get(jobs::events))
        .route_layer(from_fn_with_state(state.clone(), layers::timeout))
        .route_layer(from_fn_with_state(state.clone(), layers::auth))
        .layer(DefaultBodyLimit::max(state.max_body_bytes));
    let ops = Router::new()
        .route("/health", get(ops::health))
        .route("/ready", get(ops::ready))
        .route("/metrics", get(ops::metrics))
        .route("/openapi.json", get(ops::openapi));
    let page = Router::new()
        .route("/", get(page::index))
        .route("/jobs", get(page::jobs))
        .route("/docs", get(page::docs))
        .route("/web/{file}", get(page::asset))
        .route("/web/example/{file}", get(page::example))
        .route("/vendor/{*path}", get(page::vendor));
    v1.merge(ops)
        .merge(page)
        .method_not_allowed_fallback(layers::method_not_allowed)
        .route_layer(from_fn_with_state(state.clone(), layers::observe))
        .fallback(layers::not_found)
        .with_state(state)
}
