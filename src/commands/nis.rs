//! `nis`: a filter's recorded innovations (field logs) judged without ground truth, once
//! over finished logs ([`nis`]) or live while a log is written ([`follow`]); the JUnit file
//! and the report directory written together when the judgement is done.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::CommandError;
use crate::fieldlog::{Follower, NisReport, NisSettings, ReadOptions, Status, analyze};
use crate::output::{Outputs, check_output_file, check_report_dir, marked_json};
use crate::report::nis::html::nis_html;
use crate::report::nis::{nis_junit_xml, nis_markdown};

/// What `nis` reads and writes.
#[derive(Debug, Clone, Default)]
pub struct NisOptions {
    /// The logs judged together (PX4 ULog, CSV or JSON Lines field logs, records files).
    pub logs: Vec<PathBuf>,
    /// How the logs are read (bad rows skipped, only in the air, a truncated log's head).
    pub read: ReadOptions,
    /// The judgement's settings: α, the outlier gate, the window, the whiteness lags.
    pub settings: NisSettings,
    /// A JUnit XML report (one test case per sensor) to write.
    pub junit: Option<PathBuf>,
    /// A directory to write report.html, report.md and report.json into.
    pub report: Option<PathBuf>,
    /// Replace output files autotune did not write (an input is never replaced).
    pub force: bool,
}

/// How long a live follow runs.
#[derive(Debug, Clone, Copy, Default)]
pub struct FollowLimits {
    /// Stop after this long.
    pub limit: Option<Duration>,
    /// Stop once the file has not grown for this long.
    pub idle: Option<Duration>,
}

/// What `nis` found: the report, and its JSON as written into the report directory.
#[derive(Debug, Clone)]
pub struct NisOutcome {
    /// The per-sensor judgement and the verdict.
    pub report: NisReport,
    /// The report as JSON, marked as autotune's.
    pub json: String,
}

impl NisOptions {
    /// The outputs checked before any work: none may be an input or a file autotune did
    /// not write (without `force`).
    fn check_outputs(&self) -> Result<(), CommandError> {
        if let Some(path) = &self.junit {
            check_output_file(path, self.force).map_err(|e| e.of_flag("--junit"))?;
        }
        if let Some(dir) = &self.report {
            check_report_dir(dir, self.force).map_err(|e| e.of_flag("--report"))?;
        }
        Ok(())
    }

    /// Write the outputs of `report`, together.
    fn write(&self, report: NisReport) -> Result<NisOutcome, CommandError> {
        let json = marked_json(&report);
        let mut outputs = Outputs::replacing(self.force);
        if let Some(path) = &self.junit {
            outputs.file(path, nis_junit_xml(&report));
        }
        if let Some(dir) = &self.report {
            outputs.report_dir(dir, &nis_html(&report), &nis_markdown(&report), &json);
        }
        outputs.commit()?;
        Ok(NisOutcome { report, json })
    }
}

/// Judge the finished logs `options.logs` and write the outputs.
pub fn nis(options: &NisOptions) -> Result<NisOutcome, CommandError> {
    options.check_outputs()?;
    let report = analyze(&options.logs, &options.read, options.settings)?;
    options.write(report)
}

/// Follow the CSV or JSON Lines log at `path` while it is written, reading what was added
/// once a second and handing each second's status to `status`, until `stopped` says so,
/// a limit is reached or `status` fails; then judge all of it and write the outputs.
pub fn follow<E: From<CommandError>>(
    path: &Path,
    options: &NisOptions,
    limits: FollowLimits,
    stopped: &dyn Fn() -> bool,
    status: &mut dyn FnMut(Status) -> Result<(), E>,
) -> Result<NisOutcome, E> {
    options.check_outputs()?;
    let mut f = Follower::new(path, options.settings, options.read).map_err(CommandError::from)?;
    let start = Instant::now();
    let mut last_growth = Instant::now();
    loop {
        let tick = Instant::now();
        let before = f.bytes_read();
        f.poll().map_err(CommandError::from)?;
        if f.bytes_read() > before {
            last_growth = Instant::now();
        }
        status(f.status())?;
        let done = stopped()
            || limits.limit.is_some_and(|l| start.elapsed() >= l)
            || limits.idle.is_some_and(|i| last_growth.elapsed() >= i);
        if done {
            f.finish().map_err(CommandError::from)?;
            return Ok(options.write(f.report())?);
        }
        // Sleep out the second in slices, so that a stop ends the follow promptly.
        while tick.elapsed() < Duration::from_secs(1) && !stopped() {
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}
