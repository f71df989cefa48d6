//! `nis` on the command line: its arguments, parsed into [`crate::commands::nis`]'s
//! options; the live status printed each second; the summary or the JSON printed at the end.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use super::error::AppError;
use super::print::{print_stdout, write_painted};
use crate::commands::CommandError;
use crate::commands::nis::{FollowLimits, NisOptions, follow, nis};
use crate::fieldlog::{NisSettings, ReadOptions, Status, Window};
use crate::report::nis::nis_summary_text;

/// The arguments of `nis`.
#[derive(Debug, Clone, clap::Args)]
pub struct NisArgs {
    /// Logs: PX4 ULog (.ulg), CSV or JSON Lines field logs (docs/src/field-logs.md), or records
    /// files (docs/src/records.md) read without truth. Several files are judged together.
    #[arg(required_unless_present = "follow", value_name = "LOG")]
    logs: Vec<PathBuf>,
    /// Follow a CSV / JSON Lines log while it is written: a status line per second with the
    /// running and windowed NIS against their intervals; the full summary when it stops
    /// (Ctrl-C, --for, or --idle).
    #[arg(long, value_name = "FILE", conflicts_with = "logs")]
    follow: Option<PathBuf>,
    /// With --follow: stop after this many seconds.
    #[arg(
        long = "for",
        value_name = "SECONDS",
        requires = "follow",
        allow_negative_numbers = true
    )]
    for_seconds: Option<f64>,
    /// With --follow: stop once the file has not grown for this many seconds.
    #[arg(
        long,
        value_name = "SECONDS",
        requires = "follow",
        allow_negative_numbers = true
    )]
    idle: Option<f64>,
    /// Family-wise significance level α in (0, 0.5].
    #[arg(long, default_value_t = 0.05, allow_negative_numbers = true)]
    alpha: f64,
    /// Outlier gate: an update whose NIS a consistent filter exceeds with less than this
    /// probability is counted as an outlier, not averaged.
    #[arg(long, default_value_t = 1e-5, allow_negative_numbers = true)]
    gate: f64,
    /// Moving window: a number of updates (50) or of seconds (10s).
    #[arg(long, default_value = "50", allow_hyphen_values = true)]
    window: String,
    /// Whiteness lags L (in updates of each sensor).
    #[arg(long, default_value_t = 10, allow_negative_numbers = true)]
    lags: i64,
    /// Skip malformed rows of a CSV / JSON Lines log (and say how many) instead of stopping.
    #[arg(long)]
    skip_bad_rows: bool,
    /// PX4: judge only the updates while vehicle_land_detected says the vehicle is flying.
    #[arg(long)]
    in_air: bool,
    /// PX4: judge the data before the cut of a truncated or damaged log.
    #[arg(long)]
    allow_truncated: bool,
    /// Print the full statistics as JSON on stdout instead of the summary.
    #[arg(long)]
    json: bool,
    /// Write report.html, report.md and report.json into this directory.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Also write a JUnit XML report (one test case per sensor) to this file.
    #[arg(long, value_name = "FILE")]
    junit: Option<PathBuf>,
    /// Print nothing; the exit code is the answer.
    #[arg(long, short, conflicts_with = "json")]
    quiet: bool,
    /// Replace output files autotune did not write (by default only its own files, which
    /// carry its mark, are replaced; an input is never replaced).
    #[arg(long)]
    force: bool,
}

impl NisArgs {
    fn settings(&self) -> Result<NisSettings, AppError> {
        let lags = usize::try_from(self.lags)
            .map_err(|_| AppError::flag("--lags", format!("{} is not in 1..=100", self.lags)))?;
        NisSettings::default()
            .with_alpha(self.alpha)
            .map_err(CommandError::of_option("--alpha"))?
            .with_gate(self.gate)
            .map_err(CommandError::of_option("--gate"))?
            .with_lags(lags)
            .map_err(CommandError::of_option("--lags"))?
            .with_window(Window::parse(&self.window).map_err(CommandError::of_option("--window"))?)
            .map_err(CommandError::of_option("--window"))
            .map_err(AppError::from)
    }

    fn options(&self) -> ReadOptions {
        ReadOptions {
            skip_bad_rows: self.skip_bad_rows,
            in_air: self.in_air,
            allow_truncated: self.allow_truncated,
        }
    }
}

fn seconds(flag: &str, v: Option<f64>) -> Result<Option<Duration>, AppError> {
    v.map(|s| {
        if s.is_finite() && s > 0.0 && s < 1e9 {
            Ok(Duration::from_secs_f64(s))
        } else {
            Err(AppError::flag(
                flag,
                // `{:?}`: 1e300 as written, not its 301 digits.
                format!("{s:?} is not a number of seconds in (0, 1e9)"),
            ))
        }
    })
    .transpose()
}

/// Run `nis`.
pub fn run(a: NisArgs) -> Result<ExitCode, AppError> {
    let options = NisOptions {
        logs: a.logs.clone(),
        read: a.options(),
        settings: a.settings()?,
        junit: a.junit.clone(),
        report: a.report.clone(),
        force: a.force,
    };
    let limits = FollowLimits {
        limit: seconds("--for", a.for_seconds)?,
        idle: seconds("--idle", a.idle)?,
    };
    let outcome = match &a.follow {
        Some(path) => {
            use std::sync::atomic::Ordering;
            let stopped = || super::interrupt::STOP_FOLLOWING.load(Ordering::SeqCst);
            let mut status = |s: Status| {
                if a.quiet || a.json {
                    return Ok(());
                }
                print_stdout(|o| writeln!(o, "{s}"))
            };
            super::interrupt::FOLLOWING.store(true, Ordering::SeqCst);
            let outcome = follow(path, &options, limits, &stopped, &mut status);
            super::interrupt::FOLLOWING.store(false, Ordering::SeqCst);
            outcome?
        }
        None => nis(&options)?,
    };
    let report = &outcome.report;
    print_stdout(|stdout| {
        if a.json {
            stdout.write_all(outcome.json.as_bytes())?;
            writeln!(stdout)?;
        } else if !a.quiet {
            write_painted(stdout, &nis_summary_text(report), report.verdict.passes())?;
        }
        Ok(())
    })?;
    Ok(if report.verdict.passes() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
