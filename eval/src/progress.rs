//! How far a long evaluation has got, on stderr: indicatif's bar where stderr is a terminal,
//! and one plain line per finished run where it is a file or a pipe, so that an evaluation
//! left running in the background (`inssplat-eval score … 2> eval.log`) says in its log how far it
//! is and about how long it has left. Standard output stays the report's alone.

use std::io::IsTerminal;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Progress over `len` runs of one kind (`what`: "eval", "sweep"). The bar keeps the count,
/// the time and the run now going, drawn or hidden; `lines` says whether each finished run
/// is also written out as a line.
pub struct Progress {
    bar: ProgressBar,
    what: &'static str,
    lines: bool,
}

impl Progress {
    /// A bar on a terminal, lines elsewhere; nothing at all when `shown` is false.
    pub fn new(what: &'static str, len: u64, shown: bool) -> Self {
        let terminal = std::io::stderr().is_terminal();
        let target = if shown && terminal {
            ProgressDrawTarget::stderr()
        } else {
            ProgressDrawTarget::hidden()
        };
        let bar = ProgressBar::with_draw_target(Some(len), target);
        let template = format!(
            "{{spinner}} {what} {{pos}}/{{len}} [{{elapsed_precise}}<{{eta_precise}}] {{wide_msg}}"
        );
        bar.set_style(ProgressStyle::with_template(&template).expect("template"));
        Self { bar, what, lines: shown && !terminal }
    }

    /// Names the run now going.
    pub fn set_message(&self, message: String) {
        self.bar.set_message(message);
    }

    /// Counts the named run as done (a line: `eval 3/40 after 1m 52s, about 35m 0s left: …`).
    pub fn inc(&self) {
        self.bar.inc(1);
        if self.lines {
            let (done, len, elapsed) =
                (self.bar.position(), self.bar.length().unwrap_or(0), self.bar.elapsed());
            let left = elapsed.mul_f64(len.saturating_sub(done) as f64 / done as f64);
            eprintln!(
                "{} {done}/{len} after {}, about {} left: {}",
                self.what,
                minutes(elapsed),
                minutes(left),
                self.bar.message()
            );
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
