//! What `autotune nis` prints and writes: the summary table, JUnit XML and Markdown.

pub mod html;
mod plots;

use std::fmt::Write;

use crate::fieldlog::{NisReport, SensorReport};
use crate::report::format::fmt_g;
use crate::report::html::escape;
use crate::stats::Verdict;

/// Channels listed by name in the "not fused" line; the JSON lists all.
const NOT_FUSED_LISTED: usize = 8;
/// Warnings printed above the table; the JSON has all.
const WARNINGS_LISTED: usize = 12;

pub(super) fn rho1(s: &SensorReport) -> String {
    s.whiteness
        .iter()
        .filter(|w| w.lag == 1)
        .max_by(|a, b| a.rho.abs().total_cmp(&b.rho.abs()))
        .map_or("–".into(), |w| {
            let flag = if s
                .whiteness_tests
                .iter()
                .any(|t| t.verdict == Verdict::NotWhite)
            {
                " ✗"
            } else {
                ""
            };
            format!("{:+.3}{flag}", w.rho)
        })
}

/// The mean of the component whose zero-mean test stands out most (in σ, "✗" when it
/// fails), or a dash without a test.
pub(super) fn mean_cell(s: &SensorReport) -> String {
    s.mean_tests
        .iter()
        .max_by(|a, b| (a.z.abs() / a.threshold).total_cmp(&(b.z.abs() / b.threshold)))
        .map_or("–".into(), |t| {
            let flag = if t.verdict == Verdict::Biased {
                " ✗"
            } else {
                ""
            };
            format!("{}{flag}", crate::report::format::fmt_signed(t.mean, 2))
        })
}

pub(super) fn dropped(s: &SensorReport) -> String {
    let d = &s.dropped;
    let mut parts = Vec::new();
    if d.repeats > 0 {
        parts.push(format!("{} repeats", d.repeats));
    }
    if d.idle > 0 {
        parts.push(format!("{} idle", d.idle));
    }
    if d.invalid > 0 {
        parts.push(format!("{} invalid", d.invalid));
    }
    if d.on_ground > 0 {
        parts.push(format!("{} on ground", d.on_ground));
    }
    if d.zero_innovation > 0 {
        parts.push(format!("{} zero ν", d.zero_innovation));
    }
    if parts.is_empty() {
        "–".into()
    } else {
        parts.join(", ")
    }
}

/// The gate's settings in one line.
pub fn nis_gate_text(r: &NisReport) -> String {
    format!(
        "gate: α = {} family-wise over {} tests (each at {}); outliers: NIS beyond its {} tail, counted apart (NIS gated: the average without them; NIS all: over every update); window {}; whiteness lags 1..{}",
        r.alpha,
        r.tests,
        fmt_g(r.test_alpha),
        r.gate,
        r.window.describe(),
        r.lags
    )
}

/// The verdict line: the verdict, how many sensors fail, and what the evidence points to.
pub fn nis_verdict_line(r: &NisReport) -> String {
    let inconclusive = r
        .sensors
        .iter()
        .filter(|s| s.verdict == Verdict::Inconclusive)
        .count();
    let failing = r
        .sensors
        .iter()
        .filter(|s| !s.verdict.passes() && s.verdict != Verdict::Inconclusive)
        .count();
    let mut line = format!("verdict: {}", r.verdict.describe());
    if !r.sensors.is_empty() && failing > 0 {
        let _ = write!(line, " — {failing} of {} sensors fail", r.sensors.len());
    }
    if inconclusive > 0 && r.verdict != Verdict::Inconclusive {
        let _ = write!(
            line,
            " ({inconclusive} with too few updates to tell: not counted)"
        );
    }
    if let Some(h) = r.headline() {
        let _ = write!(line, "; {h}");
    }
    line
}

/// The human summary of a field log.
pub fn nis_summary_text(r: &NisReport) -> String {
    let mut o = String::new();
    let updates: usize = r.sensors.iter().map(|s| s.updates).sum();
    let _ = writeln!(
        o,
        "autotune nis: {} log{}, {} sensor{} with updates, {updates} updates",
        r.sources.len(),
        if r.sources.len() == 1 { "" } else { "s" },
        r.sensors.len(),
        if r.sensors.len() == 1 { "" } else { "s" },
    );
    for src in &r.sources {
        let _ = writeln!(o, "  {} ({}, {} rows)", src.path, src.format, src.rows);
        for n in &src.notes {
            let _ = writeln!(o, "    {n}");
        }
        if let Some(p) = &src.px4 {
            px4_estimator_text(&mut o, p);
        }
    }
    let listed = r.warnings.len().min(WARNINGS_LISTED);
    for w in &r.warnings[..listed] {
        let _ = writeln!(o, "warning: {w}");
    }
    if r.warnings.len() > listed {
        let _ = writeln!(
            o,
            "warning: {} more in the JSON report",
            r.warnings.len() - listed
        );
    }
    let _ = writeln!(o, "{}", nis_gate_text(r));
    let _ = writeln!(o);
    sensor_table(&mut o, r);
    for s in &r.sensors {
        if let Some(reason) = &s.inconclusive_reason {
            let _ = writeln!(o, "{}: NIS level not judged: {reason}", s.name);
        }
    }
    not_fused_lines(&mut o, r);
    let ov = &r.overall;
    if ov.nis_per_dof.is_finite() {
        let _ = writeln!(
            o,
            "overall: NIS per degree of freedom {} ({} expected, interval [{}, {}]) over {} updates, {} outliers",
            fmt_g(ov.nis_per_dof),
            fmt_g(ov.target),
            fmt_g(ov.interval.lower),
            fmt_g(ov.interval.upper),
            ov.updates,
            ov.outliers
        );
    }
    px4_channels_text(&mut o, r);
    let findings: Vec<_> = r
        .sensors
        .iter()
        .filter_map(|s| s.finding.as_ref())
        .collect();
    if !findings.is_empty() {
        let _ = writeln!(o, "\nadvice (from the NIS alone; see docs/src/nis.md):");
        for f in findings {
            let _ = writeln!(o, "  {}: {} — {}", f.component, f.action, f.evidence);
        }
    }
    let _ = writeln!(o, "\n{}", nis_verdict_line(r));
    o
}

/// The per-sensor table: updates, the gated and plain NIS averages against their interval,
/// the share of updates inside their own interval, outliers, ρ₁, the mean, the windows
/// outside, the verdict and the rows dropped.
fn sensor_table(o: &mut String, r: &NisReport) {
    let inside = format!("in {:.0}%", 100.0 * (1.0 - r.alpha));
    let width = r
        .sensors
        .iter()
        .map(|s| s.name.chars().count())
        .max()
        .unwrap_or(6)
        .max(6);
    let _ = writeln!(
        o,
        "{:<width$}  {:>7}  {:>10}  {:>10}  {:>10}  {:<22}  {:>6}  {:>8}  {:>9}  {:>9}  {:>8}  verdict   dropped",
        "sensor",
        "updates",
        "NIS gated",
        "NIS all",
        "expected",
        "interval",
        inside,
        "outliers",
        "ρ₁",
        "mean ν/√S",
        "windows"
    );
    for s in &r.sensors {
        let interval = format!(
            "[{}, {}]",
            fmt_g(s.nis.interval.lower),
            fmt_g(s.nis.interval.upper)
        );
        let windows = if s.window.windows > 0 {
            format!(
                "{:.0}% out",
                100.0 * s.window.outside as f64 / s.window.windows as f64
            )
        } else {
            "–".into()
        };
        let _ = writeln!(
            o,
            "{:<width$}  {:>7}  {:>10}  {:>10}  {:>10}  {:<22}  {:>5.1}%  {:>8}  {:>9}  {:>9}  {:>8}  {:<8}  {}",
            s.name,
            s.updates,
            fmt_g(s.nis.mean),
            fmt_g(s.nis_mean_all),
            fmt_g(s.nis.target),
            interval,
            100.0 * s.inside_fraction,
            if s.outliers_verdict == Verdict::Overconfident {
                format!("{} ✗", s.outliers)
            } else {
                s.outliers.to_string()
            },
            rho1(s),
            mean_cell(s),
            windows,
            s.verdict.label(),
            dropped(s)
        );
    }
}

/// The channels without an update, and those fused only on the ground (`--in-air` set
/// their updates aside), the first few of each by name.
fn not_fused_lines(o: &mut String, r: &NisReport) {
    let (ground, idle): (Vec<_>, Vec<_>) =
        r.not_fused.iter().partition(|n| n.dropped.on_ground > 0);
    for (list, words) in [
        (idle, "not fused (no update)"),
        (ground, "fused only on the ground (set aside by --in-air)"),
    ] {
        if list.is_empty() {
            continue;
        }
        let names: Vec<&str> = list
            .iter()
            .take(NOT_FUSED_LISTED)
            .map(|n| n.name.as_str())
            .collect();
        let more = list.len().saturating_sub(NOT_FUSED_LISTED);
        let _ = writeln!(
            o,
            "{words}: {}{}",
            names.join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        );
    }
}

/// What a PX4 log says about its estimators: publisher, release, instances, the channels not
/// judged and why, and the events of the flight.
fn px4_estimator_text(o: &mut String, p: &crate::fieldlog::Px4Info) {
    let _ = writeln!(
        o,
        "    estimator: {} ({}){}; times are seconds after the log's start",
        p.publisher,
        p.publisher_evidence,
        p.version
            .as_ref()
            .map_or(String::new(), |v| format!(", PX4 {v}"))
    );
    for i in &p.instances {
        let primary = i
            .primary_s
            .map_or(String::new(), |s| format!(", primary for {s:.1} s"));
        let _ = writeln!(
            o,
            "    ekf{}: {} logged at {:.1} Hz{primary}",
            i.index, i.topics, i.logged_hz
        );
    }
    for n in &p.not_judged {
        let _ = writeln!(
            o,
            "    not judged: {} ({} updates): {}",
            n.name, n.updates, n.reason
        );
    }
    if !p.events.is_empty() {
        let shown: Vec<String> = p
            .events
            .iter()
            .take(12)
            .map(|e| format!("{:.1} s {}", e.time, e.what))
            .collect();
        let more = p.events.len().saturating_sub(12);
        let _ = writeln!(
            o,
            "    events: {}{}",
            shown.join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        );
    }
}

/// The EKF's own view of each judged channel beside the NIS: its test ratio, the gate that
/// implies, its rejections, and how often the channel was logged against its source.
fn px4_channels_text(o: &mut String, r: &NisReport) {
    let rows: Vec<_> = r
        .sensors
        .iter()
        .filter_map(|s| s.px4.as_ref().map(|p| (s, p)))
        .collect();
    if rows.is_empty() {
        return;
    }
    let width = rows
        .iter()
        .map(|(s, _)| s.name.chars().count())
        .max()
        .unwrap_or(6)
        .max(6);
    let _ = writeln!(
        o,
        "\n{:<width$}  {:<24}  {:>10}  {:>6}  {:>8}  {:>9}  {:>9}  not judged",
        "EKF2's view", "source", "test ratio", "gate", "rejected", "updates/s", "source/s"
    );
    for (s, p) in rows {
        let opt = |v: Option<f64>| v.map_or("–".to_string(), fmt_g);
        let mut skipped = Vec::new();
        if p.fake > 0 {
            skipped.push(format!("{} fake-position", p.fake));
        }
        if p.inactive > 0 {
            skipped.push(format!("{} source off", p.inactive));
        }
        if p.at_rest > 0 {
            skipped.push(format!("{} at rest", p.at_rest));
        }
        let _ = writeln!(
            o,
            "{:<width$}  {:<24}  {:>10}  {:>6}  {:>8}  {:>9}  {:>9}  {}{}",
            s.name,
            p.source,
            opt(p.test_ratio_mean),
            p.gate.map_or("–".to_string(), |g| format!("{g:.1}")),
            p.rejected.map_or("–".to_string(), |n| n.to_string()),
            format!("{:.1}", p.update_hz),
            p.source_hz.map_or("–".to_string(), |h| format!("{h:.1}")),
            if skipped.is_empty() {
                "–".to_string()
            } else {
                skipped.join(", ")
            },
            if p.sampled {
                "  (samples of fusions)"
            } else {
                ""
            }
        );
    }
}

/// JUnit XML: one test case per sensor, named after it.
pub fn nis_junit_xml(r: &NisReport) -> String {
    let mut cases = String::new();
    let mut failures = 0;
    for s in &r.sensors {
        let name = escape(&s.name);
        if s.verdict.passes() {
            let _ = writeln!(cases, "    <testcase name=\"{name}\" classname=\"nis\"/>");
            continue;
        }
        if s.verdict == Verdict::Inconclusive {
            let _ = writeln!(
                cases,
                "    <testcase name=\"{name}\" classname=\"nis\">\n      <skipped message=\"{}\"/>\n    </testcase>",
                escape(&s.inconclusive_reason.as_ref().map_or_else(
                    || format!(
                        "inconclusive: {} updates are too few for the tests to tell a factor-2 error",
                        s.updates
                    ),
                    |r| format!("inconclusive: {r}")
                ))
            );
            continue;
        }
        failures += 1;
        let bias = s
            .mean_tests
            .iter()
            .filter(|t| t.verdict == Verdict::Biased)
            .map(|t| {
                format!(
                    ", {} mean {}σ (z = {})",
                    t.component,
                    crate::report::format::fmt_signed(t.mean, 3),
                    crate::report::format::fmt_signed(t.z, 2)
                )
            })
            .collect::<String>();
        let message = format!(
            "{}: NIS {} (expected {}, interval [{}, {}]), {} outliers, {}{bias}",
            s.verdict.label(),
            fmt_g(s.nis.mean),
            fmt_g(s.nis.target),
            fmt_g(s.nis.interval.lower),
            fmt_g(s.nis.interval.upper),
            s.outliers,
            s.whiteness_tests
                .iter()
                .find(|w| w.verdict == Verdict::NotWhite)
                .map_or("innovations white".to_string(), |w| format!(
                    "innovations correlated (ρ₁ = {:+.3})",
                    w.rho1
                ))
        );
        let body = s
            .finding
            .as_ref()
            .map_or(String::new(), |f| format!("{}: {}", f.action, f.evidence));
        let _ = writeln!(
            cases,
            "    <testcase name=\"{name}\" classname=\"nis\">\n      <failure message=\"{}\" type=\"inconsistent\">{}</failure>\n    </testcase>",
            escape(&message),
            escape(&body)
        );
    }
    if r.sensors.is_empty() {
        failures += 1;
        let _ = writeln!(
            cases,
            "    <testcase name=\"updates\" classname=\"nis\">\n      <failure message=\"no updates in the log\" type=\"inconclusive\"/>\n    </testcase>"
        );
    }
    let tests = r.sensors.len().max(1);
    format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n{}\n<testsuites>\n  <testsuite name=\"autotune nis\" tests=\"{tests}\" failures=\"{failures}\">\n{cases}  </testsuite>\n</testsuites>\n",
        crate::output::mark_comment()
    )
}

/// The summary as Markdown (the text table in a code block).
pub fn nis_markdown(r: &NisReport) -> String {
    format!(
        "{}\n# autotune nis\n\n**{}**\n\n```text\n{}```\n",
        crate::output::mark_comment(),
        nis_verdict_line(r).trim_start_matches("verdict: "),
        nis_summary_text(r)
    )
}
