//! The report of a tuning run: Markdown for people, JSON for machines.

pub mod html;

use std::fmt::Write;

use serde::Serialize;

use crate::experiment::{Experiment, Source};
use crate::explain::Explanation;
use crate::report::advice::{Recommendation, fmt_evidence};
use crate::report::consistency::cells::{StatCells, component_cells};
use crate::report::format::{fmt_fixed, fmt_g};
use crate::stats::{ConsistencyReport, StatisticSummary, Verdict};
use crate::tune::{TuneResult, TuneStatus};

/// Everything a tuning report says, for machines.
#[derive(Debug, Clone, Serialize)]
pub struct TuneReport<'a> {
    /// Problem name.
    pub problem: &'a str,
    /// Problem file.
    pub file: String,
    /// SHA-256 of the problem file (`null` for a model defined in Rust).
    pub problem_hash: Option<&'a str>,
    /// autotune version.
    pub version: &'static str,
    /// The run's results (both consistency reports included).
    pub result: &'a TuneResult,
    /// Per-parameter recommendations.
    pub recommendations: &'a [Recommendation],
    /// Why no value fit (or a bound had to be widened), most likely first; empty otherwise.
    pub explanations: &'a [Explanation],
}

fn stat_line(out: &mut String, label: &str, s: Option<&StatisticSummary>) {
    match s {
        Some(s) => {
            let c = StatCells::of(s);
            let _ = write!(
                out,
                "| {label} | {} | {} | {} | {} | {} |",
                c.average, c.target, c.interval, c.in_bounds, c.verdict
            );
        }
        None => {
            let _ = write!(out, "| {label} | – | – | – | – | not used |");
        }
    }
}

fn stats_table(out: &mut String, before: &ConsistencyReport, after: &ConsistencyReport) {
    out.push_str(
        "| filter / statistic | time average | target | interval | steps in bounds | verdict |\n",
    );
    out.push_str("| --- | --- | --- | --- | --- | --- |\n");
    for (name, r) in [("initial", before), ("tuned", after)] {
        stat_line(out, &format!("{name} ANEES"), r.nees.as_ref());
        out.push('\n');
        stat_line(out, &format!("{name} ANIS"), Some(&r.nis));
        out.push('\n');
    }
}

/// The Markdown report.
pub fn tune_markdown(
    experiment: &dyn Experiment,
    r: &TuneResult,
    recs: &[Recommendation],
    explanations: &[Explanation],
) -> String {
    let info = experiment.info();
    let mut o = String::new();
    let _ = writeln!(o, "{}", crate::output::mark_comment());
    let _ = writeln!(o, "# autotune: {}\n", info.name);
    if !info.description.is_empty() {
        let _ = writeln!(o, "{}\n", info.description);
    }
    let version = env!("CARGO_PKG_VERSION");
    let _ = match &info.source {
        Source::File { path, sha256 } => writeln!(
            o,
            "Problem file `{}` (sha256 `{}`), autotune {version}.\n",
            path.display(),
            &sha256[..sha256.len().min(12)],
        ),
        Source::Program { .. } | Source::Records { .. } => {
            writeln!(o, "Model `{}`, autotune {version}.\n", info.source.label())
        }
    };
    let _ = writeln!(
        o,
        "**Verdict before: {}. {}: {}.** Status: {:?}.\n",
        r.before.verdict.label(),
        after_heading(r),
        r.after.verdict.label(),
        r.status
    );
    if let Some(lines) = crate::report::advice::family_finding(r, explanations) {
        let _ = writeln!(o, "## {}\n", misfit_heading(r));
        for l in lines {
            let _ = writeln!(o, "- {l}");
        }
        let _ = writeln!(o);
    }
    recommendations_markdown(&mut o, recs);
    consistency_markdown(&mut o, r);
    search_markdown(&mut o, r);
    o
}

/// The advice, and the table of each parameter's start, tuned value, factor, resolution
/// and evidence.
fn recommendations_markdown(o: &mut String, recs: &[Recommendation]) {
    let _ = writeln!(o, "## Recommendations\n");
    for rec in recs {
        let _ = writeln!(o, "- {}", rec.advice);
    }
    let _ = writeln!(
        o,
        "\n| parameter | unit | initial | tuned | factor | determined within | evidence (initial filter, target 1) |"
    );
    let _ = writeln!(o, "| --- | --- | --- | --- | --- | --- | --- |");
    for rec in recs {
        let res = rec.resolution_text();
        let ev: Vec<String> = rec
            .evidence
            .iter()
            .map(|(n, v)| format!("{n} {}", fmt_evidence(*v)))
            .collect();
        let _ = writeln!(
            o,
            "| `{}` | {} | {} | {} | ×{} | {} | {} |",
            rec.param,
            rec.unit,
            fmt_g(rec.initial),
            fmt_g(rec.tuned),
            fmt_fixed(rec.factor, 3),
            res,
            ev.join(", ")
        );
    }
}

/// Consistency before and after: the runs it rests on, the confirmation, the statistics
/// and each component of the tuned filter.
fn consistency_markdown(o: &mut String, r: &TuneResult) {
    if r.confirmation.recorded {
        let _ = writeln!(
            o,
            "\n## Consistency before and after\n\nThe filter over the recorded measurements the search scored on (α = {}).\n",
            r.alpha
        );
    } else {
        let _ = writeln!(
            o,
            "\n## Consistency before and after\n\nMonte Carlo on fresh seeds never used in the search (seeds from {}, N = {} runs × T = {} steps, α = {}).\n",
            r.confirm_seed, r.runs, r.steps, r.alpha
        );
    }
    let _ = writeln!(o, "Confirmation: {}.\n", r.confirmation.text());
    stats_table(o, &r.before, &r.after);
    let _ = writeln!(
        o,
        "\nPer-component normalized errors of the tuned filter (target 1):\n"
    );
    let _ = writeln!(o, "| component | kind | value | interval | verdict |");
    let _ = writeln!(o, "| --- | --- | --- | --- | --- |");
    for c in r
        .after
        .state_components
        .iter()
        .chain(&r.after.measurement_components)
    {
        let (value, interval) = component_cells(c);
        let _ = writeln!(
            o,
            "| {} | {} | {value} | {interval} | {} |",
            c.name,
            c.kind,
            c.verdict.label()
        );
    }
}

/// How the search went: its scoring, cost, objective, refinement and what the resolution
/// means.
fn search_markdown(o: &mut String, r: &TuneResult) {
    let _ = writeln!(o, "\n## Search\n");
    let _ = writeln!(
        o,
        "- scoring: {:?} (search seed {}), {} evaluations, {} candidates diverged",
        r.scoring, r.search_seed, r.evaluations, r.diverged_evaluations
    );
    let _ = writeln!(
        o,
        "- objective: {:.4e} at the start, {:.4e} tuned (terms: mean {:.2e}, interval {:.2e}, per-step {:.2e}, components {:.2e}, whiteness {:.2e}, shape {:.2e}, bias {:.2e})",
        r.objective_initial.total,
        r.objective_final.total,
        r.objective_final.terms.mean,
        r.objective_final.terms.interval,
        r.objective_final.terms.per_step,
        r.objective_final.terms.components,
        r.objective_final.terms.whiteness,
        r.objective_final.terms.shape,
        r.objective_final.terms.bias
    );
    let _ = writeln!(
        o,
        "- refinement: {} evaluations of the gate's deviates (their sensitivity to the parameters and the steps on more runs)",
        r.refine_evaluations
    );
    if r.confirmation.recorded {
        let _ = writeln!(o, "- resolution: {}", recorded_precision(r, &[]).join(" "));
    } else {
        let _ = writeln!(
            o,
            "- resolution: a parameter is \"determined within ±x%\" when the estimate the gate's N runs would give lies within that factor of it with about 95% confidence (two standard deviations of a sandwich covariance over the {} confirmation seeds: Monte Carlo noise only)",
            r.confirmation.seeds
        );
    }
}

/// What the "after" verdict of a tune report is: with several confirmation seeds it is the
/// first seed's report, while the status rests on all of them; saying so keeps a failed
/// first seed from reading as the verdict on a tune whose confirmation holds.
pub(crate) fn after_heading(r: &TuneResult) -> &'static str {
    if r.confirmation.seeds > 1 {
        "After (first fresh seed)"
    } else {
        "After"
    }
}

/// The heading of the misfit section: no value fits, or a bound had to be widened.
pub(in crate::report) fn misfit_heading(r: &TuneResult) -> &'static str {
    if r.status == TuneStatus::Inconsistent {
        "No consistent value in this family, and why"
    } else if r.status == TuneStatus::Undecided {
        "Not consistent at the best fit, and not proven that no value fits"
    } else {
        "A search bound was in the way"
    }
}

/// `tune`'s summary as printed: the search's cost, each parameter's advice with its start
/// and tuned values, a misfit's finding, the confirmation, the files written and the
/// verdict (the `verdict:` line last).
#[allow(clippy::too_many_arguments)]
pub fn tune_summary(
    problem: &str,
    result: &TuneResult,
    settings: &crate::tune::TuneSettings,
    recs: &[Recommendation],
    explanations: &[Explanation],
    config: &std::path::Path,
    report_dir: Option<&std::path::Path>,
) -> String {
    let mut o = String::new();
    let scoring = if result.confirmation.recorded {
        "each scored on the recorded measurements".to_string()
    } else {
        format!("{} scoring", format!("{:?}", result.scoring).to_lowercase())
    };
    let _ = writeln!(
        o,
        "autotune tune {}: {} evaluations ({scoring}) in {:.2} s, {} diverged",
        problem, result.evaluations, result.seconds, result.diverged_evaluations
    );
    if result.scoring == crate::tune::Scoring::MonteCarlo && !result.confirmation.recorded {
        let _ = writeln!(o, "  truth: {}", result.truth.text());
    }
    if result.status == TuneStatus::BudgetExhausted {
        let _ = writeln!(
            o,
            "  the search stopped on its budget (--max-evals {}, --max-seconds {}): the values below are the best found so far",
            settings.max_evals(),
            settings.max_seconds()
        );
    }
    for r in recs {
        let _ = writeln!(
            o,
            "  {}  [{} → {}]",
            r.advice,
            fmt_g(r.initial),
            fmt_g(r.tuned)
        );
    }
    if result.confirmation.recorded {
        for line in recorded_precision(result, recs) {
            let _ = writeln!(o, "  {line}");
        }
    }
    if let Some(lines) = crate::report::advice::family_finding(result, explanations) {
        for l in lines {
            let _ = writeln!(o, "  {l}");
        }
    }
    confirmation_line(&mut o, result);
    let _ = writeln!(o, "  wrote {}", config.display());
    if let Some(dir) = report_dir {
        let _ = writeln!(
            o,
            "  wrote {}/report.html, report.md, report.json",
            dir.display()
        );
    }
    let _ = writeln!(o, "{}", tune_verdict_line(result));
    o
}

/// The confirmation's line: its runs and seeds (or the record), its outcome, and the
/// first seed's averages against their intervals (with the test that fails, if one does).
fn confirmation_line(o: &mut String, result: &TuneResult) {
    let line = |s: &StatisticSummary| {
        if s.steps_with_data == 0 {
            return format!("A{} no data {}", s.name, s.verdict.label());
        }
        format!(
            "A{} {} in [{}, {}] {}",
            s.name,
            fmt_fixed(s.time_average, 4),
            fmt_fixed(s.interval.lower, 4),
            fmt_fixed(s.interval.upper, 4),
            s.verdict.label()
        )
    };
    let mut parts: Vec<String> = result.after.nees.iter().map(line).collect();
    parts.push(line(&result.after.nis));
    // The averages above can each be consistent while the gate fails on another
    // of its tests (per component, whiteness): say which, so that "fail the gate"
    // and "consistent" never stand on one line unexplained.
    if !result.after.verdict.passes() {
        parts.push(format!(
            "the gate fails: {}",
            result.after.verdict.describe()
        ));
    }
    if result.confirmation.recorded {
        let _ = writeln!(
            o,
            "  confirmation: {}: {}",
            result.confirmation.text(),
            parts.join("; ")
        );
    } else {
        let _ = writeln!(
            o,
            "  confirmation ({} runs × {} steps, seeds from {}): {}; first seed: {}",
            result.runs,
            result.steps,
            result.confirm_seed,
            result.confirmation.text(),
            parts.join("; ")
        );
    }
}

/// The tune's verdict line: the start's verdict, and the tuned filter's over every
/// confirmation seed.
fn tune_verdict_line(result: &TuneResult) -> String {
    // The status rests on every confirmation seed, not on the first one's report
    // shown above: say what it rests on when the two could seem to disagree.
    let c = &result.confirmation;
    let stopped = matches!(
        result.after.verdict,
        Verdict::Diverged | Verdict::IllConditioned | Verdict::TruthOverflow
    );
    let after = if c.seeds > 1 && !stopped && (c.passed < c.seeds || !result.after.verdict.passes())
    {
        format!(
            "{} of {} fresh seeds consistent ({})",
            c.passed,
            c.seeds,
            if c.holds() {
                "as a consistent filter would be"
            } else {
                "fewer than a consistent filter"
            }
        )
    } else {
        result.after.verdict.describe().to_string()
    };
    format!(
        "verdict: before {}, after {after}",
        result.before.verdict.label(),
    )
}

/// What a tune on one record can say of each value's precision: where the record still
/// passes the gate (each parameter alone, the others at their tuned values, where `recs`
/// are given), what that rests on, and where the likelihood's interval comes from.
fn recorded_precision(result: &TuneResult, recs: &[Recommendation]) -> Vec<String> {
    let mut lines = Vec::new();
    let shown: Vec<String> = recs
        .iter()
        .filter(|r| !r.fixed && r.supported.is_some())
        .map(|r| {
            format!(
                "{} {}",
                r.param,
                crate::report::format::range_text(r.supported.as_ref(), "")
            )
        })
        .collect();
    if !shown.is_empty() {
        lines.push(format!(
            "the record passes the gate over: {} (each alone, the others at their tuned values)",
            shown.join(", ")
        ));
    }
    let what = if result.runs == 1 {
        format!("one recording ({} steps)", result.steps)
    } else {
        format!(
            "{} recordings (up to {} steps each)",
            result.runs, result.steps
        )
    };
    lines.push(format!(
        "judged on {what}, not on simulated runs, so there are no fresh seeds to confirm on and no seed-to-seed resolution; `autotune estimate` gives each parameter's 95% profile-likelihood interval, and another recording as long would narrow both by about 1/√2"
    ));
    lines
}
