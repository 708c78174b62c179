//! inssplat-server: the service. The axum HTTP API and web page ([`http`]), the batch-job
//! store and its intake ([`jobs`]), the model worker threads fed by a bounded queue
//! ([`worker`]), the scene store ([`scene_store`]), Prometheus metrics ([`metrics`]) and the
//! dataset check ([`check`]); the `inssplat` command line is a thin shell over these and
//! `inssplat-pipeline`. It never trains and never evaluates beyond scoring a job's dataset
//! scenes.

pub mod check;
pub mod http;
pub mod jobs;
pub mod metrics;
pub mod scene_store;
pub mod worker;
