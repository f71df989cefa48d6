//! The compact human summary of a consistency check.

use std::fmt::Write;

use crate::check::SeedChecks;
use crate::report::consistency::cells::{
    StatCells, component_cells, has_data, mean_cells, no_data_reason, run_spread_note, stopped_runs,
};
use crate::report::format::{compact_numbers, fmt_fixed, fmt_g};
use crate::stats::{ComponentStat, ConsistencyReport, GateMode, StatisticSummary, Verdict};

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
/// What `check` prints after the summary: `--seeds`'s lines ([`seeds_summary`]) where it
/// judged several seeds; else, where a tuned config (`tuned_config`) failed its one seed,
/// the note that one seed is one draw ([`one_seed_note`]); else nothing.
pub fn after_summary(
    seeds: Option<&SeedChecks>,
    tuned_config: bool,
    passes: bool,
    alpha: f64,
) -> String {
    match seeds {
        Some(seeds) => seeds_summary(seeds),
        None if tuned_config && !passes => one_seed_note(alpha),
        None => String::new(),
    }
}

/// `check --seeds`'s closing lines: each seed's verdict in a row, the count against the
/// band of a consistent filter, and the verdict across the seeds.
pub fn seeds_summary(seeds: &SeedChecks) -> String {
    let k = seeds.checks.len();
    let failed: Vec<String> = seeds
        .checks
        .iter()
        .filter(|c| !c.report.verdict.passes())
        .map(|c| format!("{} ({})", c.seed, c.report.verdict.label()))
        .collect();
    let mut out = format!(
        "seeds: {} of {k} pass the gate; a consistent filter passes at least {} with 99% probability\n",
        seeds.passed(),
        seeds.band_low()
    );
    if !failed.is_empty() {
        let _ = writeln!(out, "  failed: {}", failed.join(", "));
    }
    let _ = writeln!(
        out,
        "verdict across the seeds: {}",
        if seeds.passes() {
            "consistent"
        } else {
            "not consistent"
        }
    );
    out
}

/// The note under a tuned config's failed check: one seed is one draw of a random test.
pub fn one_seed_note(alpha: f64) -> String {
    format!(
        "note: this is one seed; a consistent filter fails a check with probability up to α = {alpha}, and a tune confirms its values on several: --seeds 20 judges 20 seeds as the confirmation does\n"
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::{Truth, check_seeds};
    use crate::experiment::Experiment;
    use crate::tune::tests::Mock;

    /// Mock checks on `k` seeds at θ = `at` (its truth is 1: consistent there, not at 2).
    fn seeds(at: f64, k: usize) -> SeedChecks {
        let mock = Mock::new(&[1.0], &[&[1.0]]);
        check_seeds(&mock, &[at], &mock.mc().with_seed(5), Truth::Known, k).unwrap()
    }

    #[test]
    fn several_seeds_close_with_the_count_the_band_and_the_verdict() {
        let good = seeds(1.0, 5);
        assert_eq!(
            after_summary(Some(&good), true, true, 0.05),
            "seeds: 5 of 5 pass the gate; a consistent filter passes at least 3 with 99% probability\n\
             verdict across the seeds: consistent\n"
        );
        let bad = seeds(2.0, 3);
        let verdict = bad.checks[0].report.verdict.label();
        assert_eq!(
            seeds_summary(&bad),
            format!(
                "seeds: 0 of 3 pass the gate; a consistent filter passes at least 2 with 99% probability\n  \
                 failed: 5 ({verdict}), 6 ({verdict}), 7 ({verdict})\nverdict across the seeds: not consistent\n"
            )
        );
    }

    #[test]
    fn only_a_tuned_config_that_fails_its_one_seed_gets_the_note() {
        let note = after_summary(None, true, false, 0.05);
        assert_eq!(note, one_seed_note(0.05));
        assert!(
            note.contains("α = 0.05") && note.contains("--seeds 20"),
            "{note}"
        );
        assert_eq!(after_summary(None, true, true, 0.05), "");
        assert_eq!(after_summary(None, false, false, 0.05), "");
    }
}
