//! The service's counters and latency histograms, rendered in the Prometheus text format
//! for `/metrics`: requests by route, method and status, request latency by route, pipeline
//! latency by stage, job-store latency by call, and the gauges the caller samples at scrape time (queue depth, jobs by
//! state, stored scene bytes, readiness).

use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use inssplat_proto::api::{JobState, StageTiming};

/// Upper bounds of the latency buckets, seconds.
const BUCKETS: [f64; 16] = [
    0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0,
    60.0,
];

#[derive(Debug, Clone, Default)]
struct Histogram {
    /// Observations ≤ each bucket bound (not cumulative; summed when rendered).
    counts: [u64; BUCKETS.len()],
    count: u64,
    sum: f64,
}

impl Histogram {
    fn observe(&mut self, seconds: f64) {
        if let Some(b) = BUCKETS.iter().position(|&le| seconds <= le) {
            self.counts[b] += 1;
        }
        self.count += 1;
        self.sum += seconds;
    }

    fn render(&self, out: &mut String, name: &str, label: &str, value: &str) {
        let mut cumulative = 0;
        for (le, c) in BUCKETS.iter().zip(self.counts) {
            cumulative += c;
            let _ = writeln!(out, "{name}_bucket{{{label}=\"{value}\",le=\"{le}\"}} {cumulative}");
        }
        let _ = writeln!(out, "{name}_bucket{{{label}=\"{value}\",le=\"+Inf\"}} {}", self.count);
        let _ = writeln!(out, "{name}_sum{{{label}=\"{value}\"}} {}", self.sum);
        let _ = writeln!(out, "{name}_count{{{label}=\"{value}\"}} {}", self.count);
    }
}

/// Values sampled when `/metrics` is scraped.
#[derive(Debug, Clone, Default)]
pub struct Gauges {
    pub queue_depth: usize,
    pub queue_capacity: usize,
    pub jobs_by_state: Vec<(JobState, usize)>,
    pub scene_bytes: u64,
    pub ready: bool,
}

/// Counters shared by the HTTP layer and the workers.
#[derive(Debug, Default)]
pub struct Metrics {
    /// (method, route, status) → requests.
    requests: Mutex<BTreeMap<(String, String, u16), u64>>,
    request_seconds: Mutex<BTreeMap<String, Histogram>>,
    stage_seconds: Mutex<BTreeMap<String, Histogram>>,
    /// Job-store latency by call: `claim` (found a scene), `poll` (found none), `finish`,
    /// `renew`.
    store_seconds: Mutex<BTreeMap<&'static str, Histogram>>,
    /// Tasks skipped because their requester had gone.
    dropped: AtomicU64,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    // A panic while holding a counter lock leaves valid counters: keep counting.
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Metrics {
    /// Counts one answered request; `route` is the matched route template, never the raw path.
    pub fn record_request(&self, method: &str, route: &str, status: u16, seconds: f64) {
        *lock(&self.requests)
            .entry((method.to_string(), route.to_string(), status))
            .or_default() += 1;
        lock(&self.request_seconds).entry(route.to_string()).or_default().observe(seconds);
    }

    /// Counts a task skipped because its requester had gone before it started.
    pub fn record_dropped(&self) {
        self.dropped.fetch_add(1, Ordering::Relaxed);
    }

    /// Adds one pipeline run's stage timings.
    pub fn record_stages(&self, timings: &[StageTiming]) {
        let mut stages = lock(&self.stage_seconds);
        for t in timings {
            stages.entry(t.stage.clone()).or_default().observe(t.ms / 1e3);
        }
    }

    /// Times one job-store call.
    pub fn record_store(&self, call: &'static str, seconds: f64) {
        lock(&self.store_seconds).entry(call).or_default().observe(seconds);
    }

    /// The Prometheus text exposition of everything.
    pub fn render(&self, g: &Gauges) -> String {
        let mut out = String::new();
        out.push_str("# HELP inssplat_http_requests_total HTTP requests answered.\n# TYPE inssplat_http_requests_total counter\n");
        for ((method, route, status), n) in lock(&self.requests).iter() {
            let _ = writeln!(
                out,
                "inssplat_http_requests_total{{method=\"{method}\",route=\"{route}\",status=\"{status}\"}} {n}"
            );
        }
        out.push_str("# HELP inssplat_http_request_duration_seconds Request latency by route.\n# TYPE inssplat_http_request_duration_seconds histogram\n");
        for (route, h) in lock(&self.request_seconds).iter() {
            h.render(&mut out, "inssplat_http_request_duration_seconds", "route", route);
        }
        out.push_str("# HELP inssplat_stage_duration_seconds Pipeline latency by stage.\n# TYPE inssplat_stage_duration_seconds histogram\n");
        for (stage, h) in lock(&self.stage_seconds).iter() {
            h.render(&mut out, "inssplat_stage_duration_seconds", "stage", stage);
        }
        out.push_str("# HELP inssplat_job_store_duration_seconds Job-store latency by call.\n# TYPE inssplat_job_store_duration_seconds histogram\n");
        for (call, h) in lock(&self.store_seconds).iter() {
            h.render(&mut out, "inssplat_job_store_duration_seconds", "call", call);
        }
        let dropped = self.dropped.load(Ordering::Relaxed);
        let _ = writeln!(
            out,
            "# HELP inssplat_tasks_dropped_total Tasks skipped because the client had gone.\n# TYPE inssplat_tasks_dropped_total counter\ninssplat_tasks_dropped_total {dropped}"
        );
        let gauge = |out: &mut String, name: &str, help: &str, value: f64| {
            let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} gauge\n{name} {value}");
        };
        gauge(
            &mut out,
            "inssplat_queue_depth",
            "Requests waiting for a model worker.",
            g.queue_depth as f64,
        );
        gauge(
            &mut out,
            "inssplat_queue_capacity",
            "Requests the queue holds before answering 429.",
            g.queue_capacity as f64,
        );
        gauge(
            &mut out,
            "inssplat_scene_bytes",
            "Bytes of stored scene artefacts.",
            g.scene_bytes as f64,
        );
        gauge(
            &mut out,
            "inssplat_ready",
            "1 once the model is loaded and warmed up.",
            if g.ready { 1.0 } else { 0.0 },
        );
        out.push_str("# HELP inssplat_jobs Batch jobs by state.\n# TYPE inssplat_jobs gauge\n");
        for (state, n) in &g.jobs_by_state {
            let state = serde_json::to_value(state)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default();
            let _ = writeln!(out, "inssplat_jobs{{state=\"{state}\"}} {n}");
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_cumulative_buckets_and_labels() {
        let m = Metrics::default();
        m.record_request("POST", "/v1/reconstruct", 200, 0.02);
        m.record_request("POST", "/v1/reconstruct", 429, 0.001);
        m.record_stages(&[StageTiming { stage: "model".into(), ms: 300.0 }]);
        m.record_store("claim", 0.0008);
        let text = m.render(&Gauges {
            queue_depth: 3,
            jobs_by_state: vec![(JobState::Running, 2)],
            ..Gauges::default()
        });
        assert!(text.contains("inssplat_http_requests_total{method=\"POST\",route=\"/v1/reconstruct\",status=\"429\"} 1"), "{text}");
        assert!(text.contains("inssplat_http_request_duration_seconds_bucket{route=\"/v1/reconstruct\",le=\"0.025\"} 2"), "{text}");
        assert!(
            text.contains("inssplat_stage_duration_seconds_bucket{stage=\"model\",le=\"0.25\"} 0"),
            "{text}"
        );
        assert!(
            text.contains("inssplat_stage_duration_seconds_bucket{stage=\"model\",le=\"0.5\"} 1"),
            "{text}"
        );
        assert!(
            text.contains(
                "inssplat_job_store_duration_seconds_bucket{call=\"claim\",le=\"0.001\"} 1"
            ),
            "{text}"
        );
        assert!(
            text.contains("inssplat_queue_depth 3")
                && text.contains("inssplat_jobs{state=\"running\"} 2"),
            "{text}"
        );
    }
}
