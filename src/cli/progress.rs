//! What the command line shows while the library works: progress bars on a terminal (or a
//! line every few seconds elsewhere), and the library's warnings and notices on stderr.
//! `--quiet` silences all of it.

use std::io::IsTerminal;
use std::ops::ControlFlow;
use std::time::{Duration, Instant};
use vkinverse::{Diagnostics, LogRow, Observer};

/// Seconds between progress lines where stderr is not a terminal: `VKINVERSE_PROGRESS_SECS`,
/// 10 by default.
fn progress_secs() -> f64 {
    std::env::var("VKINVERSE_PROGRESS_SECS").ok().and_then(|s| s.parse::<f64>().ok()).filter(|s| s.is_finite() && *s >= 0.0).unwrap_or(10.0)
}

/// Prints `vkinverse: warning: MESSAGE` on stderr unless quiet.
pub fn warn(quiet: bool, message: &str) {
    if !quiet {
        eprintln!("vkinverse: warning: {message}");
    }
}

/// Progress of a long task on stderr: a bar on a terminal; elsewhere (a log file, a batch
/// scheduler's output) one line every `VKINVERSE_PROGRESS_SECS` seconds (default 10), so
/// that a long render is not silent for minutes. Nothing with `quiet`.
pub struct ProgressReport {
    bar: Option<indicatif::ProgressBar>,
    lines: Option<(Duration, Instant)>,
    label: String,
    unit: String,
    start: Instant,
    total: u64,
}

impl ProgressReport {
    pub fn new(quiet: bool, label: &str, total: u64, unit: &str) -> Self {
        Self::every(quiet, label, total, unit, progress_secs())
    }

    fn every(quiet: bool, label: &str, total: u64, unit: &str, every: f64) -> Self {
        let terminal = std::io::stderr().is_terminal();
        let bar = (!quiet && terminal).then(|| {
            let bar = indicatif::ProgressBar::new(total);
            let template = format!("{{bar:40}} {{pos}}/{{len}} {unit} ({{elapsed}}, eta {{eta}}) {{msg}}");
            bar.set_style(indicatif::ProgressStyle::with_template(&template).unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()));
            bar
        });
        let lines = (!quiet && !terminal).then(|| (Duration::from_secs_f64(every), Instant::now()));
        ProgressReport { bar, lines, label: label.into(), unit: unit.into(), start: Instant::now(), total }
    }

    pub fn set_total(&mut self, total: u64) {
        self.total = total;
        if let Some(b) = &self.bar {
            b.set_length(total);
        }
    }

    /// Reports `position` of the total, with `message` (e.g. the current loss).
    pub fn set(&mut self, position: u64, message: &str) {
        if let Some(b) = &self.bar {
            b.set_position(position);
            b.set_message(message.to_string());
        }
        if let Some((every, last)) = &mut self.lines {
            if last.elapsed() >= *every {
                *last = Instant::now();
                let of = if self.total > 0 { format!("/{} ({:.0} %)", self.total, 100.0 * position as f64 / self.total as f64) } else { String::new() };
                let sep = if message.is_empty() { "" } else { "; " };
                eprintln!("{}: {position}{of} {} after {:.0} s{sep}{message}", self.label, self.unit, self.start.elapsed().as_secs_f64());
            }
        }
    }

    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

/// The loss and parameter error of a log row, as the progress bar shows them.
fn row_message(row: &LogRow) -> String {
    let err = row.param_error.map(|e| format!(" param RMSE {e:.3e}")).unwrap_or_default();
    row.loss.map(|l| format!("loss {l:.3e}{err}")).unwrap_or_default()
}

/// The command line's observer: a bar for target renders, one for the iterations of the
/// current run (named after it), and the library's messages on stderr.
pub struct Terminal {
    quiet: bool,
    targets: ProgressReport,
    iterations: ProgressReport,
}

impl Terminal {
    /// An observer of a run called `label`, of `iterations` iterations where a count bounds
    /// it.
    pub fn new(quiet: bool, label: &str, iterations: Option<u32>) -> Self {
        Terminal {
            quiet,
            targets: ProgressReport::new(quiet, "target", 0, "samples"),
            iterations: ProgressReport::new(quiet, label, iterations.unwrap_or(0) as u64, "iterations"),
        }
    }

    /// Clears the bars.
    pub fn finish(&self) {
        self.targets.finish();
        self.iterations.finish();
    }
}

impl Observer for Terminal {
    fn target_progress(&mut self, _sensor: usize, done: u32, total: u32) {
        self.targets.set_total(total as u64);
        self.targets.set(done as u64, "");
    }

    fn iteration(&mut self, row: &LogRow, _diagnostics: &[Diagnostics]) -> ControlFlow<()> {
        self.iterations.set(row.iteration as u64, &row_message(row));
        ControlFlow::Continue(())
    }

    fn resumed(&mut self, iteration: u32, changes: &[String]) {
        if !self.quiet {
            let changed = if changes.is_empty() { "no settings changed".to_string() } else { format!("changed settings: {}", changes.join(", ")) };
            eprintln!("resuming from the checkpoint at iteration {iteration}; {changed}");
        }
    }

    fn warning(&mut self, message: &str) {
        warn(self.quiet, message);
    }

    fn notice(&mut self, message: &str) {
        if !self.quiet {
            let again = if message.starts_with("interrupted") { " (Ctrl-C again stops at once)" } else { "" };
            eprintln!("vkinverse: {message}{again}");
        }
    }

    fn run_started(&mut self, label: &str, iterations: Option<u32>) {
        self.finish();
        *self = Terminal::new(self.quiet, label, iterations);
    }

    fn run_ended(&mut self, label: &str, status: &str) {
        self.finish();
        if !self.quiet && label.starts_with("job ") {
            eprintln!("{label}: {status}");
        }
    }
}
