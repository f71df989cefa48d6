//! The compact human summary of a consistency check.

use std::fmt::Write;

use crate::report::format::{compact_numbers, fmt_fixed, fmt_g, fmt_signed};
use crate::stats::{ComponentStat, ConsistencyReport, GateMode, StatisticSummary, Verdict};

/// A gate statistic's cells as every table shows them: the time average, the gate
/// interval, the share of steps inside their per-step interval, and the verdict. A
/// statistic no step had data for (no measurement in the whole run, or every run diverged
/// at once) shows `no data` and dashes, not a row of NaN.
pub(crate) struct StatCells {
    /// Time average, 4 decimals ([`fmt_fixed`]).
    pub average: String,
    /// Degrees-of-freedom target, 2 decimals.
    pub target: String,
    /// `[lower, upper]`, 4 decimals ([`fmt_fixed`]).
    pub interval: String,
    /// Percentage of steps in bounds, 1 decimal.
    pub in_bounds: String,
    /// One-word verdict.
    pub verdict: &'static str,
}

impl StatCells {
    pub(crate) fn of(s: &StatisticSummary) -> StatCells {
        if !has_data(s) {
            return StatCells {
                average: "no data".into(),
                target: "–".into(),
                interval: "–".into(),
                in_bounds: "–".into(),
                verdict: s.verdict.label(),
            };
        }
        StatCells {
            average: fmt_fixed(s.time_average, 4),
            target: fmt_fixed(s.target, 2),
            // No interval (too little data for a spread; a note says why): a dash, not NaN.
            interval: if s.interval.lower.is_nan() {
                "none (see note)".into()
            } else {
                format!(
                    "[{}, {}]",
                    fmt_fixed(s.interval.lower, 4),
                    fmt_fixed(s.interval.upper, 4)
                )
            },
            in_bounds: format!("{:.1}%", 100.0 * s.fraction_in_bounds),
            verdict: s.verdict.label(),
        }
    }
}

/// A component's value and interval cells, 3 decimals ([`fmt_fixed`]); `no data` and a dash
/// for a component that was never measured (a sensor that never reported in the run).
pub(crate) fn component_cells(c: &ComponentStat) -> (String, String) {
    if c.samples > 0.0 && c.value.is_finite() {
        (
            fmt_fixed(c.value, 3),
            format!(
                "[{}, {}]",
                fmt_fixed(c.interval.lower, 3),
                fmt_fixed(c.interval.upper, 3)
            ),
        )
    } else {
        ("no data".into(), "–".into())
    }
}

/// A component's zero-mean cells: its mean (signed, 2 decimals, "!" when the test failed)
/// and its z, or dashes without a test.
pub(crate) fn mean_cells(c: &ComponentStat) -> (String, String) {
    if !c.mean.is_finite() {
        return ("–".into(), "–".into());
    }
    let mark = if c.mean_verdict == Verdict::Biased {
        " !"
    } else {
        ""
    };
    let z = if c.mean_z.is_finite() {
        fmt_signed(c.mean_z, 1)
    } else {
        "–".into()
    };
    (format!("{}{mark}", fmt_signed(c.mean, 2)), z)
}

/// Whether any step had data for `s`.
pub(crate) fn has_data(s: &StatisticSummary) -> bool {
    s.steps_with_data > 0
}

/// Why `s` has no data, in words, for a report of `r`.
pub(crate) fn no_data_reason(s: &StatisticSummary, r: &ConsistencyReport) -> String {
    if r.diverged_runs > 0 && r.diverged_runs == r.runs {
        let why = match r.verdict {
            Verdict::TruthOverflow => "its truth overflowed",
            Verdict::IllConditioned => "a covariance was too ill-conditioned to invert",
            _ => "its filter diverged",
        };
        format!(
            "the A{} test has no data: in every run {why} before a step could be scored",
            s.name
        )
    } else {
        format!(
            "the A{} test has no data: no step of the {} runs × {} steps had {}",
            s.name,
            r.runs,
            r.steps,
            if s.name == "NIS" {
                "a measurement"
            } else {
                "a scored state"
            }
        )
    }
}

fn stat_row(out: &mut String, s: &StatisticSummary) {
    let c = StatCells::of(s);
    let _ = writeln!(
        out,
        "  A{:<5} {:>10} {:>7}   {}   {:>7}     {}",
        s.name, c.average, c.target, c.interval, c.in_bounds, c.verdict
    );
}

/// `check`'s summary as printed: [`summary_text`], with a line after the first saying so
/// when the experiment has no states and was judged by its innovations without being asked
/// to (`no_states` and not `nis_only`).
pub fn check_summary(
    problem: &str,
    params: &[(String, f64)],
    r: &ConsistencyReport,
    no_states: bool,
    nis_only: bool,
) -> String {
    let mut out = String::new();
    for (i, line) in summary_text(problem, params, r).lines().enumerate() {
        if i == 1 && no_states && !nis_only {
            out.push_str(
                "  no states (no ground truth): judged by the innovations alone, NEES absent\n",
            );
        }
        out.push_str(line);
        out.push('\n');
    }
    out
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
    component_lines(&mut out, r, gated);
    mean_lines(&mut out, r, gated);
    whiteness_line(&mut out, r, gated);
    if let Some(head) = r.diagnosis.headline() {
        let _ = writeln!(out, "  diagnosis: {head}");
        for f in &r.diagnosis.findings {
            let _ = writeln!(
                out,
                "    {}: {} → {}",
                f.component,
                compact_numbers(&f.evidence),
                f.action
            );
        }
    }
    for s in &stats {
        power_notes(&mut out, r, s);
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

/// `state` or `meas`, as the summary's component lists name a component's kind.
fn kind_word(c: &ComponentStat) -> &'static str {
    if c.kind == "state" { "state" } else { "meas" }
}

/// The components off their target 1, or (when none is) the three worst of those inside
/// their intervals.
fn component_lines(out: &mut String, r: &ConsistencyReport, gated: &str) {
    let off: Vec<String> = r
        .state_components
        .iter()
        .chain(&r.measurement_components)
        .filter(|c| matches!(c.verdict, Verdict::Overconfident | Verdict::Underconfident))
        .map(|c| {
            let (value, interval) = component_cells(c);
            format!("{} {} {value} {interval}", kind_word(c), c.name)
        })
        .collect();
    if !off.is_empty() {
        let _ = writeln!(
            out,
            "  components off their target 1{gated}: {}",
            off.join("; ")
        );
        return;
    }
    // One run of a filter without an error map leaves its state components untested (no
    // spread to judge them by): they are listed apart, never as inside an interval.
    let untested: Vec<String> = r
        .state_components
        .iter()
        .chain(&r.measurement_components)
        .filter(|c| c.samples > 0.0 && c.value.is_finite() && c.interval.lower.is_nan())
        .map(|c| format!("{} {} {}", kind_word(c), c.name, fmt_fixed(c.value, 3)))
        .collect();
    let worst: Vec<String> = r
        .worst_components(usize::MAX)
        .into_iter()
        .filter(|c| !c.interval.lower.is_nan())
        .take(3)
        .map(|c| format!("{} {} {}", kind_word(c), c.name, fmt_fixed(c.value, 3)))
        .collect();
    if !worst.is_empty() {
        let _ = writeln!(
            out,
            "  components (target 1, all inside their intervals; worst first): {}",
            worst.join("; ")
        );
    }
    if !untested.is_empty() {
        let _ = writeln!(
            out,
            "  components not tested (one run of a filter without an error map gives no spread to judge them by; a second recording would): {}",
            untested.join("; ")
        );
    }
}

/// The components whose errors or innovations are not zero-mean, or (when all are) the
/// three largest means by |z|.
fn mean_lines(out: &mut String, r: &ConsistencyReport, gated: &str) {
    let comps: Vec<&ComponentStat> = r
        .state_components
        .iter()
        .chain(&r.measurement_components)
        .filter(|c| c.mean_z.is_finite())
        .collect();
    let mean_text = |c: &ComponentStat| {
        let (mean, z) = mean_cells(c);
        format!("{} {} {mean} (z {z})", kind_word(c), c.name)
    };
    let biased: Vec<String> = comps
        .iter()
        .filter(|c| c.mean_verdict == Verdict::Biased)
        .map(|c| mean_text(c))
        .collect();
    if !biased.is_empty() {
        let _ = writeln!(
            out,
            "  components not zero-mean{gated} (mean in σ): {}",
            biased.join("; ")
        );
    } else if !comps.is_empty() {
        let mut by_z = comps.clone();
        by_z.sort_by(|a, b| b.mean_z.abs().total_cmp(&a.mean_z.abs()));
        let top: Vec<String> = by_z.iter().take(3).map(|c| mean_text(c)).collect();
        let _ = writeln!(
            out,
            "  component means (target 0, all zero-mean by test; largest |z| first): {}",
            top.join("; ")
        );
    }
}

/// The measurement components whose innovations are not white, if any.
fn whiteness_line(out: &mut String, r: &ConsistencyReport, gated: &str) {
    let white: Vec<String> = r
        .whiteness_tests
        .iter()
        .filter(|w| w.verdict == Verdict::NotWhite)
        .map(|w| {
            format!(
                "{} ρ₁ = {:+.3} (portmanteau {} > {}, {} lags)",
                w.component,
                w.rho1,
                fmt_fixed(w.statistic, 1),
                fmt_fixed(w.threshold, 1),
                w.dof
            )
        })
        .collect();
    if !white.is_empty() {
        let _ = writeln!(out, "  innovations not white{gated}: {}", white.join("; "));
    }
}

/// What statistic `s` can and cannot tell at this N and T: a wide run-to-run spread, no
/// data, too few degrees of freedom for its time average or its per-step tests.
fn power_notes(out: &mut String, r: &ConsistencyReport, s: &StatisticSummary) {
    if let Some(note) = run_spread_note(s) {
        let _ = writeln!(out, "  note: {note}");
    }
    if !has_data(s) {
        let _ = writeln!(out, "  note: {}", no_data_reason(s, r));
    } else if r.diverged_runs >= r.runs {
        // Every run stopped part-way: the stopped-runs line says why, and "add runs or
        // steps" would be the wrong advice.
    } else if !s.has_power {
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

/// The gate in one line: which tests, how many, and the level of each.
pub fn gate_text(r: &ConsistencyReport) -> String {
    let what = match r.gate {
        GateMode::Full => {
            "full (time averages, every component's spread and zero mean, innovation whiteness)"
        }
        GateMode::Mean => "mean (time-averaged ANEES/ANIS only)",
    };
    if r.gate == GateMode::Full && r.mean_alpha < r.statistic_alpha {
        let means = (r.statistic_alpha / r.mean_alpha).round() as usize;
        format!(
            "{what}; {} tests, each at level {:.4} but the {means} zero-mean tests, which share one such level ({:.5} each), so that a consistent filter fails with probability at most α = {} (Šidák)",
            r.tests, r.statistic_alpha, r.mean_alpha, r.alpha
        )
    } else {
        format!(
            "{what}; {} tests, each at level {:.4} so that a consistent filter fails with probability at most α = {} (Šidák)",
            r.tests, r.statistic_alpha, r.alpha
        )
    }
}

/// What stopped runs early, in words, by the verdict it set.
pub(crate) fn stopped_runs(verdict: Verdict) -> &'static str {
    match verdict {
        Verdict::TruthOverflow => "the truth overflowed",
        Verdict::IllConditioned => "a covariance was too ill-conditioned to invert",
        _ => "filter diverged",
    }
}

/// An interval's ends relative to its target: "±4.4%" where they sit alike, or
/// "−8.4% / +8.9%" (a chi-square interval, or one cut at zero).
fn spread_text(target: f64, i: &crate::stats::Interval) -> String {
    let below = 100.0 * (target - i.lower) / target;
    let above = 100.0 * (i.upper - target) / target;
    if (below - above).abs() < 0.05 {
        format!("±{:.1}%", 0.5 * (below + above))
    } else {
        format!("−{below:.1}% / +{above:.1}%")
    }
}

/// For a statistic whose gate interval rests on the spread of the per-run sums (a filter that
/// supplies no error map), the sentence that says so and what it costs: the interval's
/// half-width against the textbook one's, each relative to the target (for 128 runs × 400
/// steps of a 2-state filter, about ±4.4% instead of −1.2% / +1.2%).
///
/// For one run (a single recording), the sentence says the interval comes from batch means
/// over its steps instead, and what a second recording would add.
pub fn run_spread_note(s: &StatisticSummary) -> Option<String> {
    let half = |i: &crate::stats::Interval| spread_text(s.target, i);
    if s.interval.lower.is_nan() && s.time_average.is_finite() {
        return Some(format!(
            "the filter supplies no error map, and one run of {} steps is too short for the spread of its A{} sum over time (batch means needs {} blocks of {} steps), so A{} has no interval and no verdict: a recording of at least {} steps, or a second recording, would give one",
            s.steps_with_data,
            s.name,
            crate::stats::MIN_BATCHES,
            crate::stats::MIN_BATCH_STEPS,
            s.name,
            crate::stats::MIN_BATCHES * crate::stats::MIN_BATCH_STEPS,
        ));
    }
    if let Some(b) = s.batch_spread_batches {
        return Some(format!(
            "the filter supplies no error map and there is one run, so the A{} interval comes from batch means: the spread of the sums of {b} blocks of consecutive steps (Student t, {} degrees of freedom), widened to contain the textbook interval: {} around {} instead of {} (it catches only larger errors; a longer or a second recording narrows it)",
            s.name,
            b - 1,
            half(&s.interval),
            fmt_g(s.target),
            half(&s.naive_interval),
        ));
    }
    s.run_spread_runs.map(|n| {
        format!(
            "the filter supplies no error map, so the A{} interval comes from the spread of the {n} per-run sums (Student t), widened to contain the textbook interval: {} around {} instead of {} (it catches only larger errors; more runs narrow it)",
            s.name,
            half(&s.interval),
            fmt_g(s.target),
            half(&s.naive_interval),
        )
    })
}
