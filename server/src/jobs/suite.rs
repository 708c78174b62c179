//! One behavioural suite for every job store: each test runs against SQLite in a temporary
//! folder and against a real PostgreSQL server started for it ([`super::test_postgres`]).

use std::path::PathBuf;
use std::time::Duration;

use inssplat_proto::api::JobState;

use super::postgres::PostgresStore;
use super::sqlite::SqliteStore;
use super::{JobStore, NewJob, SceneOutcome};
use inssplat_e2e::postgres::TestPostgres;

/// A store's database.
trait Backend {
    /// A new handle on the backend's database, as the server opens it again after a restart.
    fn open(&self) -> Box<dyn JobStore>;
}

struct Sqlite(tempfile::TempDir);

impl Backend for Sqlite {
    fn open(&self) -> Box<dyn JobStore> {
        Box::new(SqliteStore::open(&self.0.path().join("jobs.sqlite")).unwrap())
    }
}

/// Claims of a second in the tests, so that a dead replica's run out quickly.
const TEST_LEASE: Duration = Duration::from_secs(1);

struct Postgres {
    url: String,
    /// Stops the server when the test ends.
    _server: TestPostgres,
}

impl Backend for Postgres {
    fn open(&self) -> Box<dyn JobStore> {
        Box::new(self.replica("a"))
    }
}

impl Postgres {
    fn replica(&self, name: &str) -> PostgresStore {
        PostgresStore::connect(&self.url, name, TEST_LEASE).unwrap()
    }
}

fn sqlite() -> Sqlite {
    Sqlite(tempfile::tempdir().unwrap())
}

fn postgres() -> Postgres {
    let server = TestPostgres::start();
    Postgres { url: server.database("jobs"), _server: server }
}

fn job(id: &str, scenes: usize) -> NewJob {
    NewJob {
        id: id.into(),
        scenes: (0..scenes).map(|i| (format!("s{i}"), PathBuf::from(format!("/in/{i}")))).collect(),
        vocabulary: None,
        refine_steps: None,
    }
}

fn scenes_run_in_order_and_an_interrupted_one_reruns_under_its_id(backend: &impl Backend) {
    let store = backend.open();
    store
        .create(&NewJob {
            vocabulary: Some(vec!["lamp".into()]),
            refine_steps: Some(5),
            ..job("a", 2)
        })
        .unwrap();
    let first = store.claim().unwrap().unwrap();
    assert_eq!((first.job_id.as_str(), first.index, first.refine_steps), ("a", 0, Some(5)));
    assert_eq!(first.vocabulary, Some(vec!["lamp".to_string()]));
    let metrics = serde_json::json!({"psnr": 20.0});
    assert!(store.finish(&first, &SceneOutcome::Done { metrics: Some(metrics) }).unwrap());
    let second = store.claim().unwrap().unwrap();
    assert_eq!(store.status("a").unwrap().unwrap().state, JobState::Running);
    drop(store); // the process dies with scene 1 running

    let store = backend.open();
    assert_eq!(store.requeue_interrupted().unwrap(), 1);
    let again = store.claim().unwrap().unwrap();
    assert_eq!((again.index, &again.scene_id), (1, &second.scene_id));
    assert!(store.finish(&again, &SceneOutcome::Failed { error: "bad photo".into() }).unwrap());
    assert!(store.claim().unwrap().is_none());
    let s = store.status("a").unwrap().unwrap();
    assert_eq!((s.state, s.done, s.total), (JobState::Done, 2, 2));
    assert_eq!(s.scenes[0].metrics.as_ref().unwrap()["psnr"], 20.0);
    assert_eq!(s.scenes[1].error.as_deref(), Some("bad photo"));
    assert!(store.count_by_state().unwrap().contains(&(JobState::Done, 1)));
}

fn cancel_stops_queued_scenes(backend: &impl Backend) {
    let store = backend.open();
    store.create(&job("a", 3)).unwrap();
    let running = store.claim().unwrap().unwrap();
    let s = store.cancel("a").unwrap().unwrap();
    assert_eq!(s.state, JobState::Cancelled);
    assert_eq!(
        s.scenes.iter().map(|s| s.state).collect::<Vec<_>>(),
        [JobState::Running, JobState::Cancelled, JobState::Cancelled]
    );
    assert!(store.claim().unwrap().is_none());
    assert!(store.finish(&running, &SceneOutcome::Done { metrics: None }).unwrap());
    assert!(store.cancel("nope").unwrap().is_none() && store.status("nope").unwrap().is_none());
    assert!(store.count_by_state().unwrap().contains(&(JobState::Cancelled, 1)));
}

/// Handles claiming at once from several threads, as replicas would, get every scene once.
fn concurrent_claims_take_each_scene_once(backend: &impl Backend) {
    let scenes = 24;
    backend.open().create(&job("a", scenes)).unwrap();
    let claimed: Vec<usize> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..3)
            .map(|_| {
                let store = backend.open();
                scope.spawn(move || {
                    let mut mine = Vec::new();
                    while let Some(task) = store.claim().unwrap() {
                        assert!(
                            store.finish(&task, &SceneOutcome::Done { metrics: None }).unwrap()
                        );
                        mine.push(task.index);
                    }
                    mine
                })
            })
            .collect();
        workers.into_iter().flat_map(|w| w.join().unwrap()).collect()
    });
    let mut sorted = claimed.clone();
    sorted.sort_unstable();
    assert_eq!(sorted, (0..scenes).collect::<Vec<_>>(), "each scene once: {claimed:?}");
    let s = backend.open().status("a").unwrap().unwrap();
    assert_eq!((s.state, s.done), (JobState::Done, scenes));
}

macro_rules! suite {
    ($backend:ident) => {
        mod $backend {
            #[test]
            fn scenes_run_in_order_and_an_interrupted_one_reruns_under_its_id() {
                super::scenes_run_in_order_and_an_interrupted_one_reruns_under_its_id(
                    &super::$backend(),
                );
            }

            #[test]
            fn cancel_stops_queued_scenes() {
                super::cancel_stops_queued_scenes(&super::$backend());
            }

            #[test]
            fn concurrent_claims_take_each_scene_once() {
                super::concurrent_claims_take_each_scene_once(&super::$backend());
            }
        }
    };
}

suite!(sqlite);
suite!(postgres);

/// PostgreSQL only, where a claim is a lease: once it runs out another replica runs the scene,
/// and the first one's late result is refused rather than counted twice; a replica's restart
/// requeues only its own scenes.
#[test]
fn a_lapsed_claim_is_taken_over_and_its_late_result_refused() {
    let backend = postgres();
    let (slow, fast) = (backend.replica("slow"), backend.replica("fast"));
    slow.create(&job("a", 1)).unwrap();
    let first = slow.claim().unwrap().unwrap();
    assert!(fast.claim().unwrap().is_none(), "held while the claim lasts");
    assert_eq!(backend.replica("fast").requeue_interrupted().unwrap(), 0, "not its scene");
    std::thread::sleep(TEST_LEASE + Duration::from_millis(200));
    let second = fast.claim().unwrap().unwrap();
    assert_eq!((second.index, &second.scene_id), (0, &first.scene_id));
    let late = slow.finish(&first, &SceneOutcome::Done { metrics: None }).unwrap();
    assert!(!late, "the result of a claim that ran out is refused");
    assert!(fast.finish(&second, &SceneOutcome::Failed { error: "x".into() }).unwrap());
    let s = fast.status("a").unwrap().unwrap();
    assert_eq!((s.state, s.scenes[0].error.as_deref()), (JobState::Failed, Some("x")));
}

/// PostgreSQL only: a renewed claim outlasts its first term, and only its holder renews it.
#[test]
fn a_renewed_claim_is_not_taken_over() {
    let backend = postgres();
    let (runner, other) = (backend.replica("runner"), backend.replica("other"));
    runner.create(&job("a", 1)).unwrap();
    let task = runner.claim().unwrap().unwrap();
    std::thread::sleep(TEST_LEASE * 7 / 10);
    assert!(runner.renew(&task).unwrap());
    assert!(!other.renew(&task).unwrap(), "not the other replica's claim");
    std::thread::sleep(TEST_LEASE * 6 / 10); // past the first term, within the second
    assert!(other.claim().unwrap().is_none(), "still held");
    assert!(runner.finish(&task, &SceneOutcome::Done { metrics: None }).unwrap());
}
