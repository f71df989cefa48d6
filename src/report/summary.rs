//! The compact human summary of a consistency check.

use std::fmt::Write;

use crate::stats::{ConsistencyReport, GateMode, StatisticSummary, Verdict};

/// A gate statistic's cells as every table shows them: the time average, the gate
/// interval, the share of steps inside their per-step interval, and the verdict.
pub(crate) struct StatCells {
    /// Time average, 4 decimals.
    pub average: String,
    /// `[lower, upper]`, 4 decimals.
    pub interval: String,
    /// Percentage of steps in bounds, 1 decimal.
    pub in_bounds: String,
    /// One-word verdict.
    pub verdict: &'static str,
}

impl StatCells {
    pub(crate) fn of(s: &StatisticSummary) -> StatCells {
        StatCells {
            average: format!("{:.4}", s.time_average),
            interval: format!("[{:.4}, {:.4}]", s.interval.lower, s.interval.upper),
            in_bounds: format!("{:.1}%", 100.0 * s.fraction_in_bounds),
            verdict: s.verdict.label(),
        }
    }
}

fn stat_row(out: &mut String, s: &StatisticSummary) {
    let c = StatCells::of(s);
    let _ = writeln!(
        out,
        "  A{:<5} {:>10} {:>7.2}   {}   {:>7}     {}",
        s.name, c.average, s.target, c.interval, c.in_bounds, c.verdict
    );
}

/// A summary a person reads in seconds: the gate statistics with their intervals, the
/// fraction of steps in bounds, the worst components, warnings about power, and the verdict.
pub fn summary_text(problem: &str, params: &[(String, f64)], r: &ConsistencyReport) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "autotune check {problem}: N = {} runs × T = {} steps, α = {}",
        r.runs, r.steps, r.alpha
    );
    if !params.is_empty() {
        let p: Vec<String> = params
            .iter()
            .map(|(n, v)| format!("{n} = {}", fmt_g(*v)))
            .collect();
        let _ = writeln!(out, "  params: {}", p.join(", "));
    }
    let _ = writeln!(
        out,
        "  stat    time-avg  target   gate interval        in bounds   verdict"
    );
    let stats: Vec<&StatisticSummary> = r.nees.iter().chain(std::iter::once(&r.nis)).collect();
    for s in &stats {
        stat_row(&mut out, s);
    }
    let _ = writeln!(out, "  gate: {}", gate_text(r));
    let gated = if r.gate == GateMode::Full {
        ""
    } else {
        " (diagnostic, not gated)"
    };
    let off: Vec<String> = r
        .state_components
        .iter()
        .chain(&r.measurement_components)
        .filter(|c| matches!(c.verdict, Verdict::Overconfident | Verdict::Underconfident))
        .map(|c| {
            let kind = if c.kind == "state" { "state" } else { "meas" };
            format!(
                "{kind} {} {:.3} [{:.3}, {:.3}]",
                c.name, c.value, c.interval.lower, c.interval.upper
            )
        })
        .collect();
    if off.is_empty() {
        let worst = r.worst_components(3);
        if !worst.is_empty() {
            let w: Vec<String> = worst
                .iter()
                .map(|c| {
                    let kind = if c.kind == "state" { "state" } else { "meas" };
                    format!("{kind} {} {:.3}", c.name, c.value)
                })
                .collect();
            let _ = writeln!(
                out,
                "  components (target 1, all inside their intervals; worst first): {}",
                w.join("; ")
            );
        }
    } else {
        let _ = writeln!(
            out,
            "  components off their target 1{gated}: {}",
            off.join("; ")
        );
    }
    let white: Vec<String> = r
        .whiteness_tests
        .iter()
        .filter(|w| w.verdict == Verdict::NotWhite)
        .map(|w| {
            format!(
                "{} ρ₁ = {:+.3} (portmanteau {:.1} > {:.1}, {} lags)",
                w.component, w.rho1, w.statistic, w.threshold, w.dof
            )
        })
        .collect();
    if !white.is_empty() {
        let _ = writeln!(out, "  innovations not white{gated}: {}", white.join("; "));
    }
    if let Some(head) = r.diagnosis.headline() {
        let _ = writeln!(out, "  diagnosis: {head}");
        for f in &r.diagnosis.findings {
            let _ = writeln!(out, "    {}: {} → {}", f.component, f.evidence, f.action);
        }
    }
    for s in &stats {
        if let Some(note) = run_spread_note(s) {
            let _ = writeln!(out, "  note: {note}");
        }
        // Runs that all stopped leave no data: the reason below says why, and "add runs or
        // steps" would be the wrong advice.
        if r.diverged_runs >= r.runs {
            continue;
        }
        if !s.has_power {
            let _ = writeln!(
                out,
                "  warning: the time-averaged A{} test has only {:.1} effective degrees of freedom and cannot tell a factor-2 covariance error; add runs or steps",
                s.name, s.effective_dof
            );
        } else if !s.per_step_has_power {
            let _ = writeln!(
                out,
                "  note: per-step A{} tests have too few degrees of freedom (N·dof small) to detect a factor-2 error at a single step; the time average carries the verdict",
                s.name
            );
        }
    }
    if r.diverged_runs > 0 {
        let first = r
            .divergences
            .first()
            .map(|d| format!(" (first: run {}, {})", d.run, d.reason))
            .unwrap_or_default();
        let _ = writeln!(
            out,
            "  {} in {} of {} runs{first}",
            stopped_runs(r.verdict),
            r.diverged_runs,
            r.runs
        );
    }
    let _ = writeln!(out, "verdict: {}", r.verdict.describe());
    out
}

/// The gate in one line: which tests, how many, and the level of each.
pub fn gate_text(r: &ConsistencyReport) -> String {
    let what = match r.gate {
        GateMode::Full => "full (time averages, every component, innovation whiteness)",
        GateMode::Mean => "mean (time-averaged ANEES/ANIS only)",
    };
    format!(
        "{what}; {} tests, each at level {:.4} so that a consistent filter fails with probability at most α = {} (Šidák)",
        r.tests, r.statistic_alpha, r.alpha
    )
}

/// What stopped runs early, in words, by the verdict it set.
pub(crate) fn stopped_runs(verdict: Verdict) -> &'static str {
    match verdict {
        Verdict::TruthOverflow => "the truth overflowed",
        Verdict::IllConditioned => "a covariance was too ill-conditioned to invert",
        _ => "filter diverged",
    }
}

/// For a statistic whose gate interval rests on the spread of the per-run sums (a filter that
/// supplies no error map), the sentence that says so.
pub fn run_spread_note(s: &StatisticSummary) -> Option<String> {
    s.run_spread_runs.map(|n| {
        format!(
            "the filter supplies no error map, so the A{} interval comes from the spread of the {n} per-run sums (Student t), widened to contain the textbook interval",
            s.name
        )
    })
}

/// A number with four significant digits, in scientific notation when it is very small or
/// very large.
pub fn fmt_g(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{v:.3e}")
    } else {
        let digits = if a == 0.0 {
            0
        } else {
            (3 - a.log10().floor() as i32).max(0) as usize
        };
        format!("{v:.digits$}")
    }
}
