//! Progress on stderr: a bar with its ETA for a long check, and a tune's evaluations,
//! stage and notes. Drawn only where someone watches (the command line decides: a
//! terminal, not `--quiet`).

use std::sync::OnceLock;

use indicatif::{ProgressBar, ProgressStyle};

use crate::check::CheckProgress;
use crate::tune::Observer;

/// A check's bar, drawn only for runs long enough to be worth one.
#[derive(Debug, Default)]
pub struct CheckBar {
    bar: OnceLock<ProgressBar>,
}

impl CheckBar {
    /// A bar that appears when a long run starts.
    pub fn new() -> Self {
        CheckBar::default()
    }
}

impl CheckProgress for CheckBar {
    fn start(&self, runs: usize, steps: usize, fast_path: bool) {
        // The linear fast path steps about 100 times faster than the others.
        let long = if fast_path { 20_000_000 } else { 200_000 };
        if runs.saturating_mul(steps) < long {
            return;
        }
        let b = ProgressBar::new(runs as u64);
        b.set_style(
            ProgressStyle::with_template(
                "check [{bar:30}] {pos}/{len} runs, {elapsed} (ETA {eta})",
            )
            .expect("a valid template")
            .progress_chars("=> "),
        );
        let _ = self.bar.set(b);
    }

    fn runs_done(&self, done: usize) {
        if let Some(b) = self.bar.get() {
            b.set_position(done as u64);
        }
    }

    fn finish(&self) {
        if let Some(b) = self.bar.get() {
            b.finish_and_clear();
        }
    }
}

/// A tune's progress on stderr: a bar over the evaluation budget where one is drawn, and
/// the search's notes (unless quiet).
#[derive(Debug)]
pub struct TuneProgress {
    bar: Option<ProgressBar>,
    quiet: bool,
}

impl TuneProgress {
    /// Progress over `max_evals` evaluations: a bar if `bar`, notes on stderr unless
    /// `quiet`.
    pub fn new(max_evals: usize, bar: bool, quiet: bool) -> Self {
        let bar = bar.then(|| {
            let b = ProgressBar::new(max_evals as u64);
            b.set_style(
                ProgressStyle::with_template(
                    "{prefix:>7} [{bar:30}] {pos}/{len} evals, {elapsed} (ETA {eta}) {msg}",
                )
                .expect("a valid template")
                .progress_chars("=> "),
            );
            b
        });
        TuneProgress { bar, quiet }
    }

    /// Clear the bar (the search is over).
    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

impl Observer for TuneProgress {
    fn evaluation(&self, evals: usize, best: f64) {
        if let Some(b) = &self.bar {
            b.set_position(evals as u64);
            b.set_message(format!("best objective {best:.3e}"));
        }
    }

    fn phase(&self, name: &str) {
        if let Some(b) = &self.bar {
            b.set_prefix(name.to_string());
        }
    }

    fn note(&self, line: &str) {
        match &self.bar {
            Some(b) => b.println(format!("note: {line}")),
            None if !self.quiet => eprintln!("note: {line}"),
            None => {}
        }
    }
}
