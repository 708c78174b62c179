//! How far a long evaluation has got, on stderr: indicatif's bar where stderr is a terminal,
//! and one plain line per finished run where it is a file or a pipe, so that an evaluation
//! left running in the background (`inssplat eval … 2> eval.log`) says in its log how far it
//! is and about how long it has left. Standard output stays the report's alone.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

/// Progress over `len` runs of one kind (`what`: "eval", "sweep").
pub struct Progress {
    bar: ProgressBar,
    lines: Option<Lines>,
}

/// The plain-line form: what is being counted, how many, since when, and the run now going.
struct Lines {
    what: &'static str,
    len: u64,
    start: Instant,
    state: Mutex<(u64, String)>,
}

impl Progress {
    /// A bar on a terminal, lines elsewhere; nothing at all when `shown` is false.
    pub fn new(what: &'static str, len: u64, shown: bool) -> Self {
        let terminal = std::io::stderr().is_terminal();
        let bar = if shown && terminal { ProgressBar::new(len) } else { ProgressBar::hidden() };
        let template = format!("{{spinner}} {what} {{pos}}/{{len}} [{{elapsed_precise}}<{{eta_precise}}] {{wide_msg}}");
        bar.set_style(ProgressStyle::with_template(&template).expect("template"));
        let lines = (shown && !terminal).then(|| Lines { what, len, start: Instant::now(), state: Mutex::new((0, String::new())) });
        Self { bar, lines }
    }

    /// Names the run now going.
    pub fn set_message(&self, message: String) {
        if let Some(lines) = &self.lines {
            lines.state.lock().expect("progress lock").1.clone_from(&message);
        }
        self.bar.set_message(message);
    }

    /// Counts the named run as done (a line: `eval 3/40 after 1m 52s, about 35m 0s left: …`).
    pub fn inc(&self) {
        self.bar.inc(1);
        if let Some(lines) = &self.lines {
            let mut state = lines.state.lock().expect("progress lock");
            state.0 += 1;
            let elapsed = lines.start.elapsed();
            let left = elapsed.mul_f64(lines.len.saturating_sub(state.0) as f64 / state.0 as f64);
            eprintln!("{} {}/{} after {}, about {} left: {}", lines.what, state.0, lines.len, minutes(elapsed), minutes(left), state.1);
        }
    }

    pub fn finish_and_clear(&self) {
        self.bar.finish_and_clear();
    }
}

/// `1m 52s`, or `7s` under a minute.
fn minutes(d: Duration) -> String {
    let s = d.as_secs();
    match s / 60 {
        0 => format!("{s}s"),
        m => format!("{m}m {}s", s % 60),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_in_minutes_and_seconds() {
        assert_eq!(minutes(Duration::from_millis(7400)), "7s");
        assert_eq!(minutes(Duration::from_secs(112)), "1m 52s");
        assert_eq!(minutes(Duration::from_secs(2100)), "35m 0s");
    }
}
