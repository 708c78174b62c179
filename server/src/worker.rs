//! The model workers: OS threads that each own an ONNX Runtime session and share one text
//! encoder, fed by a bounded queue of interactive tasks (reconstruct, query). A full queue
//! answers at once ([`SubmitError::Overloaded`], with a retry delay from the recent task
//! time) instead of growing; a task whose requester has gone (client disconnected or timed
//! out) is dropped before it costs compute. When the queue is empty a worker claims the next
//! batch-job scene from the job store, so jobs use the idle time and interactive requests
//! never wait behind a whole batch. Stopping lets each worker finish what it is running; job
//! scenes not yet started stay queued in the store for the next start.

use std::panic::AssertUnwindSafe;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TryRecvError, TrySendError};
use std::sync::{Arc, Mutex, OnceLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use inssplat_proto::api::{QueryResponse, ReconstructResponse};
use inssplat_text::LabelCache;
use tokio::sync::{broadcast, oneshot};

use crate::jobs::{JobStore, SceneOutcome, SceneTask};
use crate::metrics::Metrics;
use crate::scene_store::{SceneId, SceneStore};
use inssplat_pipeline::backend::Model;
use inssplat_pipeline::reconstruct::{InputImage, PipelineConfig, PipelineError, reconstruct};
use inssplat_pipeline::saved::Saved;
use inssplat_pipeline::stages::decode::DecodeError;
use inssplat_pipeline::{output, query};

/// How long an idle worker waits on the queue before looking for job scenes again.
const IDLE_POLL: Duration = Duration::from_millis(100);
/// How long a worker waits for the job store after an error before claiming again.
const STORE_RETRY: Duration = Duration::from_secs(1);
/// How long a worker keeps trying to record a finished scene while the job store is down.
const RECORD_FOR: Duration = Duration::from_secs(120);

/// Why a task failed.
#[derive(Debug, thiserror::Error)]
pub enum TaskError {
    /// The input is at fault; the message names it.
    #[error("{0}")]
    Invalid(String),
    /// The input is in a format the service does not read; the message names it.
    #[error("{0}")]
    Unsupported(String),
    #[error("{0}")]
    Internal(String),
}

fn internal(e: impl std::fmt::Display) -> TaskError {
    TaskError::Internal(e.to_string())
}

/// Work for a model worker; each answers through its `reply`.
pub enum Task {
    /// Reconstruct `images`, refining for `refine_steps` (`None`: the server's setting).
    Reconstruct {
        images: Vec<InputImage>,
        vocabulary: Vec<String>,
        refine_steps: Option<usize>,
        reply: oneshot::Sender<Result<ReconstructResponse, TaskError>>,
    },
    /// Query the stored scene in `dir` (mask PNG paths in the answer are under `dir`).
    Query { dir: PathBuf, text: String, reply: oneshot::Sender<Result<QueryResponse, TaskError>> },
}

impl Task {
    /// Whether the requester stopped waiting.
    fn abandoned(&self) -> bool {
        match self {
            Task::Reconstruct { reply, .. } => reply.is_closed(),
            Task::Query { reply, .. } => reply.is_closed(),
        }
    }
}

/// Why a task was not queued.
#[derive(Debug, thiserror::Error)]
pub enum SubmitError {
    #[error("the model is still loading")]
    NotReady,
    #[error(
        "the service is busy: {capacity} requests are already waiting; retry in {retry_after_s} s"
    )]
    Overloaded { capacity: usize, retry_after_s: u64 },
    #[error("the service is shutting down")]
    Stopped,
}

/// What the workers are started with.
pub struct WorkerConfig {
    pub model: PathBuf,
    /// ONNX Runtime threads per worker.
    pub threads: usize,
    pub workers: usize,
    /// Interactive tasks that may wait; one more is refused.
    pub queue: usize,
    pub pipeline: PipelineConfig,
}

/// What workers share with the HTTP layer.
pub struct Shared {
    pub scenes: SceneStore,
    pub jobs: Arc<dyn JobStore>,
    pub metrics: Arc<Metrics>,
    /// The id of a job whenever one of its scenes changes state.
    pub job_events: broadcast::Sender<String>,
}

struct PoolState {
    depth: AtomicUsize,
    capacity: usize,
    workers: usize,
    /// The model version, once every worker has loaded and warmed up.
    ready: OnceLock<String>,
    stop: AtomicBool,
    /// Moving average of a task's wall time, milliseconds.
    mean_task_ms: AtomicU64,
}

/// The worker threads and their queue.
pub struct Pool {
    tx: Mutex<Option<SyncSender<Task>>>,
    state: Arc<PoolState>,
    handles: Arc<Mutex<Vec<JoinHandle<()>>>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Pool {
    /// Starts loading the text encoder and one model per worker in the background; the
    /// receiver gets the model version when all are warm, or the error that stopped them.
    pub fn start(
        config: WorkerConfig,
        shared: Arc<Shared>,
    ) -> (Arc<Pool>, oneshot::Receiver<anyhow::Result<String>>) {
        let (tx, rx) = std::sync::mpsc::sync_channel(config.queue);
        let state = Arc::new(PoolState {
            depth: AtomicUsize::new(0),
            capacity: config.queue,
            workers: config.workers.max(1),
            ready: OnceLock::new(),
            stop: AtomicBool::new(false),
            mean_task_ms: AtomicU64::new(1000),
        });
        let pool = Arc::new(Pool {
            tx: Mutex::new(Some(tx)),
            state: state.clone(),
            handles: Arc::default(),
        });
        let (started, startup) = oneshot::channel();
        let handles = pool.handles.clone();
        let loader = std::thread::Builder::new().name("model-loader".into()).spawn(move || {
            let result = load_and_spawn(config, shared, state, Arc::new(Mutex::new(rx)), &handles);
            let _ = started.send(result);
        });
        if let Err(e) = loader {
            tracing::error!("cannot start the model loader thread: {e}");
        }
        (pool, startup)
    }

    /// The loaded model's version, `None` while warming up.
    pub fn model_version(&self) -> Option<&str> {
        self.state.ready.get().map(String::as_str)
    }

    pub fn queue_depth(&self) -> usize {
        self.state.depth.load(Ordering::Relaxed)
    }

    pub fn queue_capacity(&self) -> usize {
        self.state.capacity
    }

    /// Queues `task`, or says why not without waiting.
    pub fn submit(&self, task: Task) -> Result<(), SubmitError> {
        if self.state.ready.get().is_none() {
            return Err(SubmitError::NotReady);
        }
        let guard = lock(&self.tx);
        let tx = guard.as_ref().ok_or(SubmitError::Stopped)?;
        self.state.depth.fetch_add(1, Ordering::Relaxed);
        match tx.try_send(task) {
            Ok(()) => Ok(()),
            Err(e) => {
                self.state.depth.fetch_sub(1, Ordering::Relaxed);
                Err(match e {
                    TrySendError::Full(_) => {
                        let waiting = (self.state.capacity + self.state.workers) as u64;
                        let ms = self.state.mean_task_ms.load(Ordering::Relaxed) * waiting
                            / self.state.workers as u64;
                        SubmitError::Overloaded {
                            capacity: self.state.capacity,
                            retry_after_s: ms.div_ceil(1000).max(1),
                        }
                    }
                    TrySendError::Disconnected(_) => SubmitError::Stopped,
                })
            }
        }
    }

    /// Refuses new tasks, lets every worker finish the task or job scene it is running, and
    /// waits for them; queued job scenes stay in the store.
    pub fn stop(&self) {
        self.state.stop.store(true, Ordering::SeqCst);
        lock(&self.tx).take();
        let handles: Vec<_> = lock(&self.handles).drain(..).collect();
        for h in handles {
            if h.join().is_err() {
                tracing::error!("a model worker panicked while stopping");
            }
        }
    }
}

fn load_and_spawn(
    config: WorkerConfig,
    shared: Arc<Shared>,
    state: Arc<PoolState>,
    rx: Arc<Mutex<Receiver<Task>>>,
    handles: &Mutex<Vec<JoinHandle<()>>>,
) -> anyhow::Result<String> {
    let labels = Arc::new(inssplat_pipeline::vocab::label_cache()?);
    let models = (0..state.workers)
        .map(|_| Model::load(&config.model, config.threads))
        .collect::<Result<Vec<_>, _>>()?;
    let network = &models[0].network;
    if config.pipeline.photo_aspect && network.size_multiple.is_none() {
        // Refused at start rather than on every request.
        let resolution = network.resolution;
        return Err(inssplat_pipeline::reconstruct::PipelineError::SquareOnly { resolution }.into());
    }
    let version = network.model_version.clone();
    for (i, model) in models.into_iter().enumerate() {
        let worker = Worker {
            model,
            labels: labels.clone(),
            pipeline: config.pipeline.clone(),
            shared: shared.clone(),
            state: state.clone(),
        };
        let rx = rx.clone();
        let handle = std::thread::Builder::new()
            .name(format!("model-worker-{i}"))
            .spawn(move || worker.run(&rx))?;
        lock(handles).push(handle);
    }
    let _ = state.ready.set(version.clone());
    Ok(version)
}

struct Worker {
    model: Model,
    labels: Arc<LabelCache>,
    pipeline: PipelineConfig,
    shared: Arc<Shared>,
    state: Arc<PoolState>,
}

/// What a worker does next.
enum Next {
    Task(Task),
    Scene(SceneTask),
    Idle,
    Stop,
}

impl Worker {
    fn run(mut self, rx: &Mutex<Receiver<Task>>) {
        loop {
            match self.next(rx) {
                Next::Task(task) => {
                    self.state.depth.fetch_sub(1, Ordering::Relaxed);
                    if task.abandoned() {
                        self.shared.metrics.record_dropped();
                        continue;
                    }
                    let start = Instant::now();
                    self.run_task(task);
                    self.time(start);
                }
                Next::Scene(scene) => {
                    let start = Instant::now();
                    self.run_scene(&scene);
                    self.time(start);
                }
                Next::Idle => {}
                Next::Stop => return,
            }
        }
    }

    /// An interactive task if one waits, else a job scene, else a task within [`IDLE_POLL`]
    /// ([`STORE_RETRY`] when the job store failed).
    fn next(&self, rx: &Mutex<Receiver<Task>>) -> Next {
        if self.state.stop.load(Ordering::SeqCst) {
            return Next::Stop;
        }
        match lock(rx).try_recv() {
            Ok(task) => return Next::Task(task),
            Err(TryRecvError::Disconnected) => return Next::Stop,
            Err(TryRecvError::Empty) => {}
        }
        let mut wait = IDLE_POLL;
        let start = Instant::now();
        let claimed = self.shared.jobs.claim();
        let call = if matches!(claimed, Ok(Some(_))) { "claim" } else { "poll" };
        self.shared.metrics.record_store(call, start.elapsed().as_secs_f64());
        match claimed {
            Ok(Some(scene)) => return Next::Scene(scene),
            Ok(None) => {}
            Err(e) => {
                tracing::error!("job store: cannot claim a scene: {e:#}");
                wait = STORE_RETRY;
            }
        }
        match lock(rx).recv_timeout(wait) {
            Ok(task) => Next::Task(task),
            Err(RecvTimeoutError::Timeout) => Next::Idle,
            Err(RecvTimeoutError::Disconnected) => Next::Stop,
        }
    }

    fn time(&self, start: Instant) {
        let ms = start.elapsed().as_millis() as u64;
        let old = self.state.mean_task_ms.load(Ordering::Relaxed);
        self.state.mean_task_ms.store((old * 4 + ms) / 5, Ordering::Relaxed);
    }

    fn run_task(&mut self, task: Task) {
        match task {
            Task::Reconstruct { images, vocabulary, refine_steps, reply } => {
                let config = self.pipeline.with_refine_steps(refine_steps);
                let result = catch(|| self.reconstruct(&images, &vocabulary, &config));
                let _ = reply.send(result);
            }
            Task::Query { dir, text, reply } => {
                let result = catch(|| {
                    let saved = Saved::load(&dir).map_err(|e| internal(format!("{e:#}")))?;
                    query::run_query(&saved, &self.labels, &text)
                        .map(|(answer, _)| answer)
                        .map_err(|e| internal(format!("{e:#}")))
                });
                let _ = reply.send(result);
            }
        }
    }

    fn reconstruct(
        &mut self,
        images: &[InputImage],
        vocabulary: &[String],
        config: &PipelineConfig,
    ) -> Result<ReconstructResponse, TaskError> {
        let rec = reconstruct(&mut self.model, &self.labels, images, vocabulary, config).map_err(
            |e| match e {
                PipelineError::Decode(DecodeError::Unsupported { .. }) => {
                    TaskError::Unsupported(e.to_string())
                }
                PipelineError::ViewCount(_)
                | PipelineError::Decode(_)
                | PipelineError::EmptyVocabulary => TaskError::Invalid(e.to_string()),
                other => internal(other),
            },
        )?;
        self.shared.metrics.record_stages(&rec.timings);
        let id = SceneId::new();
        let staged = self.shared.scenes.staging(&id).map_err(internal)?;
        output::write_reconstruction(&rec, images, staged.dir())
            .map_err(|e| internal(format!("{e:#}")))?;
        self.shared.scenes.commit(staged).map_err(|e| internal(format!("{e:#}")))?;
        Ok(ReconstructResponse { scene_id: id.to_string(), ..output::summary(&rec) })
    }

    /// Runs a claimed job scene and commits its outcome; its input folder goes once committed.
    /// Where the store's claims lapse, a second thread renews this one while the scene runs.
    fn run_scene(&mut self, task: &SceneTask) {
        tracing::info!("job {} scene {} ({}): started", task.job_id, task.index, task.name);
        let _ = self.shared.job_events.send(task.job_id.clone());
        let (jobs, metrics) = (self.shared.jobs.clone(), self.shared.metrics.clone());
        let (done, renewals) = std::sync::mpsc::channel::<()>();
        let renewer = jobs.lease().map(|lease| {
            let task = task.clone();
            std::thread::spawn(move || {
                renew_while_running(jobs.as_ref(), &metrics, &task, lease, &renewals)
            })
        });
        let result = catch(|| {
            let id: SceneId = task.scene_id.parse().map_err(TaskError::Internal)?;
            let staged = self.shared.scenes.staging(&id).map_err(internal)?;
            let (timings, metrics) = crate::jobs::run::run_scene(
                &mut self.model,
                &self.labels,
                &self.pipeline,
                task,
                staged.dir(),
            )
            .map_err(|e| internal(format!("{e:#}")))?;
            self.shared.scenes.commit(staged).map_err(internal)?;
            self.shared.metrics.record_stages(&timings);
            Ok(metrics)
        });
        drop(done);
        if let Some(renewer) = renewer {
            let _ = renewer.join();
        }
        let outcome = match result {
            Ok(metrics) => SceneOutcome::Done { metrics },
            Err(e) => SceneOutcome::Failed { error: e.to_string() },
        };
        if record(self.shared.jobs.as_ref(), &self.shared.metrics, task, &outcome) {
            tracing::info!(
                "job {} scene {} ({}): {}",
                task.job_id,
                task.index,
                task.name,
                match &outcome {
                    SceneOutcome::Done { .. } => "done".to_string(),
                    SceneOutcome::Failed { error } => format!("failed: {error}"),
                }
            );
            if let Err(e) = std::fs::remove_dir_all(&task.input) {
                tracing::warn!(
                    "job {}: cannot remove the input of scene {}: {e}",
                    task.job_id,
                    task.index
                );
            }
        }
        let _ = self.shared.job_events.send(task.job_id.clone());
    }
}

/// Records `outcome` for `task`, trying again for [`RECORD_FOR`] while the store cannot be
/// reached (a database restarting); whether it was recorded. When it was not, the claim ran
/// out or stays unrecorded, and the scene is run again, by whichever replica claims it.
fn record(
    jobs: &dyn JobStore,
    metrics: &Metrics,
    task: &SceneTask,
    outcome: &SceneOutcome,
) -> bool {
    let start = Instant::now();
    let mut wait = Duration::from_millis(100);
    loop {
        let call = Instant::now();
        let finished = jobs.finish(task, outcome);
        metrics.record_store("finish", call.elapsed().as_secs_f64());
        match finished {
            Ok(true) => return true,
            Ok(false) => {
                tracing::warn!(
                    "job {} scene {}: not recorded, the claim ran out first (another replica runs it, or it was cancelled)",
                    task.job_id,
                    task.index
                );
                return false;
            }
            Err(e) if start.elapsed() + wait > RECORD_FOR => {
                tracing::error!(
                    "job {} scene {}: cannot record it, giving up: {e:#}",
                    task.job_id,
                    task.index
                );
                return false;
            }
            Err(e) => {
                tracing::warn!(
                    "job {} scene {}: cannot record it yet, trying again in {wait:?}: {e:#}",
                    task.job_id,
                    task.index
                );
                std::thread::sleep(wait);
                wait = (wait * 2).min(Duration::from_secs(5));
            }
        }
    }
}

/// Renews the claim on `task` every third of `lease` until `stop`'s sender is dropped.
fn renew_while_running(
    jobs: &dyn JobStore,
    metrics: &Metrics,
    task: &SceneTask,
    lease: Duration,
    stop: &Receiver<()>,
) {
    while let Err(RecvTimeoutError::Timeout) = stop.recv_timeout(lease / 3) {
        let call = Instant::now();
        let renewed = jobs.renew(task);
        metrics.record_store("renew", call.elapsed().as_secs_f64());
        match renewed {
            Ok(true) => {}
            Ok(false) => {
                tracing::warn!(
                    "job {} scene {}: the claim lapsed; another replica may run it",
                    task.job_id,
                    task.index
                );
                return;
            }
            Err(e) => tracing::warn!(
                "job {} scene {}: cannot renew the claim: {e:#}",
                task.job_id,
                task.index
            ),
        }
    }
}

/// Runs `f`, turning a panic into an internal error (a bad input must never take a worker down).
fn catch<T>(f: impl FnOnce() -> Result<T, TaskError>) -> Result<T, TaskError> {
    std::panic::catch_unwind(AssertUnwindSafe(f)).unwrap_or_else(|p| {
        let what = p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()));
        Err(TaskError::Internal(format!(
            "internal error: {}",
            what.unwrap_or_else(|| "panic".into())
        )))
    })
}
