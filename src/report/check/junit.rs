//! JUnit XML, the test-report format CI systems display.

use std::fmt::Write;

use crate::report::consistency::cells::has_data;
use crate::report::format::fmt_fixed;
use crate::report::html::escape;
use crate::stats::{ConsistencyReport, GateMode, StatisticSummary, Verdict};

fn case(name: &str, class: &str, failure: Option<(String, String)>) -> String {
    match failure {
        None => format!(
            "    <testcase name=\"{}\" classname=\"{}\"/>\n",
            escape(name),
            escape(class)
        ),
        Some((msg, body)) => format!(
            "    <testcase name=\"{}\" classname=\"{}\">\n      <failure message=\"{}\" type=\"inconsistent\">{}</failure>\n    </testcase>\n",
            escape(name),
            escape(class),
            escape(&msg),
            escape(&body)
        ),
    }
}

fn stat_case(s: &StatisticSummary, class: &str) -> String {
    let name = format!("time-averaged A{}", s.name);
    let failure = (!s.verdict.passes()).then(|| {
        if !has_data(s) {
            let message = format!("A{}: no data (no step had data in any run)", s.name);
            let body = format!("{message}; {}", s.verdict.describe());
            return (message, body);
        }
        (
            if s.interval.contains(s.time_average) {
                format!(
                    "A{} = {}: {} (effective degrees of freedom {:.1})",
                    s.name,
                    fmt_fixed(s.time_average, 4),
                    s.verdict.label(),
                    s.effective_dof
                )
            } else {
                format!(
                    "A{} = {} outside [{}, {}]: {}",
                    s.name,
                    fmt_fixed(s.time_average, 4),
                    fmt_fixed(s.interval.lower, 4),
                    fmt_fixed(s.interval.upper, 4),
                    s.verdict.label()
                )
            },
            format!(
                "A{} time average {}, target {:.3}, interval [{}, {}] (effective dof {:.1}); {:.1}% of steps inside the per-step interval; {}",
                s.name,
                fmt_fixed(s.time_average, 6),
                s.target,
                fmt_fixed(s.interval.lower, 6),
                fmt_fixed(s.interval.upper, 6),
                s.effective_dof,
                100.0 * s.fraction_in_bounds,
                s.verdict.describe()
            ),
        )
    });
    case(&name, class, failure)
}

/// One case for the zero-mean tests of every component (the full gate's), failing with
/// the components whose errors do not average zero.
fn mean_case(report: &ConsistencyReport, class: &str) -> String {
    let biased: Vec<String> = report
        .state_components
        .iter()
        .chain(&report.measurement_components)
        .filter(|c| c.mean_verdict == Verdict::Biased)
        .map(|c| {
            format!(
                "{} {} mean {}σ (z = {})",
                c.kind,
                c.name,
                crate::report::format::fmt_signed(c.mean, 3),
                crate::report::format::fmt_signed(c.mean_z, 2)
            )
        })
        .collect();
    let failure = (!biased.is_empty()).then(|| {
        (
            format!("not zero-mean: {}", biased.join("; ")),
            format!("{}: {}", Verdict::Biased.describe(), biased.join("; ")),
        )
    });
    case("errors zero-mean", class, failure)
}

/// A JUnit XML report with one test case per gate statistic (and one for divergence),
/// named so a failing case says which statistic failed.
pub fn junit_xml(problem: &str, report: &ConsistencyReport) -> String {
    let class = format!("autotune.check.{problem}");
    let mut cases = String::new();
    if let Some(n) = &report.nees {
        cases += &stat_case(n, &class);
    }
    cases += &stat_case(&report.nis, &class);
    if report.gate == GateMode::Full {
        cases += &mean_case(report, &class);
    }
    let div = (report.diverged_runs > 0).then(|| {
        let first = report
            .divergences
            .first()
            .map(|d| format!("first: run {} step {}: {}", d.run, d.step, d.reason))
            .unwrap_or_default();
        (
            format!(
                "{} in {} of {} runs",
                crate::report::consistency::cells::stopped_runs(report.verdict),
                report.diverged_runs,
                report.runs
            ),
            first,
        )
    });
    cases += &case("filter stays positive definite", &class, div);
    let tests = cases.matches("<testcase").count();
    let failures = cases.matches("<failure").count();
    let mut out = String::new();
    out.push_str("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    out.push_str(&crate::output::mark_comment());
    out.push('\n');
    let _ = writeln!(
        out,
        "<testsuites name=\"autotune\" tests=\"{tests}\" failures=\"{failures}\" errors=\"0\">"
    );
    let _ = writeln!(
        out,
        "  <testsuite name=\"{}\" tests=\"{tests}\" failures=\"{failures}\" errors=\"0\" skipped=\"0\">",
        escape(&format!("autotune check {problem}"))
    );
    out += &cases;
    out.push_str("  </testsuite>\n</testsuites>\n");
    out
}
