//! The HTML report of `autotune nis`: the verdict and the reader's warnings, the summary
//! table and the advice, the PX4 estimator section for a PX4 log, then per sensor its NIS
//! over time, its innovation in the ±√S band, its histogram against the χ² density and its
//! innovations' autocorrelation. Self-contained: inline SVG, no scripts, no network.

mod captions;
mod px4;

use std::fmt::Write;

use crate::fieldlog::{NisReport, SensorReport};
use crate::report::format::{compact_numbers, fmt_g};
use crate::report::html::{escape, figure, head_styled};
use crate::report::nis::plots::{
    TimeAxis, innovation_svg, nis_histogram_svg, nis_series_svg, nis_whiteness_svg, series_scale,
};
use crate::report::nis::{dropped, mean_cell, nis_gate_text, nis_verdict_line, rho1};
use crate::stats::Verdict;
use captions::{
    count, histogram_caption, innovation_caption, interval, num, series_caption, short,
    whiteness_caption,
};

/// Channels not fused listed inline; more are folded away.
const NOT_FUSED_INLINE: usize = 8;

/// Style of this report beyond the common one: a rule between sensors, the plots' width.
const NIS_STYLE: &str = "section{border-top:1px solid #bbb;margin-top:1.2em}\
section h3{margin:.5em 0 .2em}.row figure{max-width:440px}td.num{text-align:right}\
.fail{font-weight:bold}td{white-space:nowrap}\
.warnings{border-left:4px solid #555;padding-left:.6em}td.note{white-space:normal;min-width:14em}";

/// The time axis of the report's plots: the log's own origin and its events for a PX4
/// log, plain seconds otherwise.
fn time_axis(r: &NisReport) -> TimeAxis {
    let mut px4 = px4::infos(r).peekable();
    if px4.peek().is_none() {
        return TimeAxis::plain();
    }
    let mut events: Vec<_> = px4.flat_map(|(_, p)| p.events.iter().cloned()).collect();
    events.sort_by(|a, b| a.time.total_cmp(&b.time));
    TimeAxis::px4(events)
}

fn warnings(o: &mut String, r: &NisReport) {
    if r.warnings.is_empty() {
        return;
    }
    o.push_str("<div class=\"warnings\"><p><b>Warnings</b></p><ul>");
    for w in &r.warnings {
        let _ = write!(o, "<li>{}</li>", escape(w));
    }
    o.push_str("</ul></div>\n");
}

/// What a PX4 EKF said about the sensor and the parameters to change, under its heading.
fn px4_lines(o: &mut String, r: &NisReport, s: &SensorReport) {
    if let Some(c) = &s.px4 {
        let mut parts: Vec<String> = Vec::new();
        if !c.source.is_empty() {
            parts.push(format!("aiding source: {}", c.source));
        }
        parts.extend(px4::ekf_line(c));
        parts.extend(px4::fusion_note(px4::info_for(r), &s.name, c));
        if !parts.is_empty() {
            let _ = writeln!(o, "<p>EKF2: {}.</p>", escape(&parts.join("; ")));
        }
    }
    if !s.parameters.is_empty() {
        let lines: Vec<String> = s
            .parameters
            .iter()
            .map(|p| format!("<code>{}</code>", escape(&p.text)))
            .collect();
        let _ = writeln!(o, "<p>EKF2 parameters: {}.</p>", lines.join("; "));
    }
}

/// The unit of a sensor's innovations: its noise parameter's (PX4), when known.
fn innovation_unit(s: &SensorReport) -> &str {
    s.px4
        .as_ref()
        .and_then(|p| p.unit.as_deref())
        .into_iter()
        .chain(s.parameters.iter().map(|p| p.unit.as_str()))
        .find(|u| !u.is_empty())
        .unwrap_or("units of the log")
}

fn verdict_cell(v: Verdict) -> String {
    let class = if v.passes() { "" } else { " class=\"fail\"" };
    format!("<td{class}>{}</td>", escape(v.label()))
}

fn sources(o: &mut String, r: &NisReport) {
    o.push_str("<ul>");
    for src in &r.sources {
        let _ = write!(
            o,
            "<li><code>{}</code> ({}, {} rows{})",
            escape(&src.path),
            escape(&src.format),
            src.rows,
            if src.skipped_rows > 0 {
                format!(", {} malformed rows skipped", src.skipped_rows)
            } else {
                String::new()
            }
        );
        if !src.notes.is_empty() {
            o.push_str("<ul>");
            for n in &src.notes {
                let _ = write!(o, "<li>{}</li>", escape(n));
            }
            o.push_str("</ul>");
        }
        o.push_str("</li>");
    }
    o.push_str("</ul>\n");
}

fn summary_table(o: &mut String, r: &NisReport) {
    let _ = writeln!(
        o,
        "<table><tr><th>sensor</th><th>updates</th><th>dropped rows</th><th>NIS average</th><th>expected</th><th>interval</th><th>in per-update {:.0}% interval</th><th>outliers (expected)</th><th>ρ₁</th><th>mean ν/√S</th><th>windows outside</th><th>verdict</th></tr>",
        100.0 * (1.0 - r.alpha)
    );
    for (i, s) in r.sensors.iter().enumerate() {
        let outliers = format!(
            "{}{} ({})",
            s.outliers,
            if s.outliers_verdict == Verdict::Overconfident {
                " ✗"
            } else {
                ""
            },
            short(s.outliers_expected)
        );
        let windows = if s.window.windows > 0 {
            format!(
                "{:.0}% of {}",
                100.0 * s.window.outside as f64 / s.window.windows as f64,
                s.window.windows
            )
        } else {
            "–".into()
        };
        let _ = writeln!(
            o,
            "<tr><td><a href=\"#sensor-{i}\">{}</a></td><td class=\"num\">{}</td><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td><td class=\"num\">{:.1}%</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>{}</tr>",
            escape(&s.name),
            s.updates,
            escape(&dropped(s)),
            num(s.nis.mean),
            num(s.nis.target),
            interval(s),
            100.0 * s.inside_fraction,
            escape(&outliers),
            escape(&rho1(s)),
            escape(&mean_cell(s)),
            escape(&windows),
            verdict_cell(s.verdict)
        );
    }
    o.push_str("</table>\n");
}

fn not_fused(o: &mut String, r: &NisReport) {
    if r.not_fused.is_empty() {
        return;
    }
    let names: Vec<String> = r
        .not_fused
        .iter()
        .map(|n| format!("<code>{}</code>", escape(&n.name)))
        .collect();
    let head = format!(
        "Not fused: {} in the log without an update",
        count(r.not_fused.len() as u64, "channel")
    );
    if names.len() > NOT_FUSED_INLINE {
        let _ = writeln!(
            o,
            "<details><summary>{head}</summary><p>{}.</p></details>",
            names.join(", ")
        );
    } else {
        let _ = writeln!(o, "<p>{head}: {}.</p>", names.join(", "));
    }
}

fn overall(o: &mut String, r: &NisReport) {
    let ov = &r.overall;
    if ov.nis_per_dof.is_finite() {
        let _ = writeln!(
            o,
            "<p>All sensors pooled: NIS per degree of freedom {} ({} expected, interval [{}, {}]) over {} updates, {} outliers.</p>",
            fmt_g(ov.nis_per_dof),
            fmt_g(ov.target),
            fmt_g(ov.interval.lower),
            fmt_g(ov.interval.upper),
            ov.updates,
            ov.outliers
        );
    }
}

fn advice(o: &mut String, r: &NisReport) {
    let findings: Vec<_> = r
        .sensors
        .iter()
        .filter_map(|s| s.finding.as_ref())
        .collect();
    if findings.is_empty() {
        return;
    }
    o.push_str("<h2>Advice</h2><p>From the NIS alone (see docs/src/nis.md): without ground truth the innovations tell whether S fits them, and their whiteness hints at which of Q and R is off.</p><ul>");
    for f in findings {
        let _ = write!(
            o,
            "<li><code>{}</code>: {} — {}</li>",
            escape(&f.component),
            escape(&f.action),
            escape(&compact_numbers(&f.evidence))
        );
    }
    o.push_str("</ul>\n");
}

fn component_table(o: &mut String, s: &SensorReport) {
    if s.component_stats.is_empty() && s.mean_tests.is_empty() {
        return;
    }
    o.push_str("<table><tr><th>component</th><th>mean ν²/S (target 1)</th><th>interval</th><th>updates</th><th>verdict</th><th>mean ν/√S (target 0)</th><th>z</th><th>effective samples</th><th>zero mean</th></tr>");
    for name in &s.components {
        let c = s.component_stats.iter().find(|c| &c.name == name);
        let t = s.mean_tests.iter().find(|t| &t.component == name);
        if c.is_none() && t.is_none() {
            continue;
        }
        let _ = write!(o, "<tr><td><code>{}</code></td>", escape(name));
        match c {
            Some(c) => {
                let _ = write!(
                    o,
                    "<td class=\"num\">{}</td><td>[{}, {}]</td><td class=\"num\">{}</td>{}",
                    num(c.value),
                    num(c.interval.lower),
                    num(c.interval.upper),
                    c.samples,
                    verdict_cell(c.verdict)
                );
            }
            // A one-component sensor: its second moment is the sensor's NIS above.
            None => o.push_str("<td colspan=\"4\">see the NIS average</td>"),
        }
        match t {
            Some(t) => {
                let _ = write!(
                    o,
                    "<td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>{}",
                    crate::report::format::fmt_signed(t.mean, 3),
                    crate::report::format::fmt_signed(t.z, 2),
                    num(t.n_eff),
                    verdict_cell(t.verdict)
                );
            }
            None => o.push_str("<td colspan=\"4\">–</td>"),
        }
        o.push_str("</tr>");
    }
    o.push_str("</table>\n");
}

fn sensor_section(o: &mut String, r: &NisReport, axis: &TimeAxis, i: usize, s: &SensorReport) {
    let _ = writeln!(
        o,
        "<section id=\"sensor-{i}\"><h3>{} — {}</h3>",
        escape(&s.name),
        escape(s.verdict.label())
    );
    let (t0, t1) = s.time_span;
    let _ = write!(
        o,
        "<p>{} from {} s to {} s: NIS average {} ({} expected, interval {}), {}, {:.1}% of updates inside their own interval",
        count(s.updates as u64, "update"),
        num(t0),
        num(t1),
        num(s.nis.mean),
        num(s.nis.target),
        interval(s),
        count(s.outliers as u64, "outlier"),
        100.0 * s.inside_fraction
    );
    if s.outliers > 0 {
        let _ = write!(
            o,
            "; the average over every update, outliers included, is {}",
            num(s.nis_mean_all)
        );
    }
    if let (Some(lo), Some(hi)) = (s.window.min, s.window.max) {
        let _ = write!(
            o,
            "; window average from {} (at {} s) to {} (at {} s)",
            num(lo.0),
            num(lo.1),
            num(hi.0),
            num(hi.1)
        );
    }
    o.push_str(".</p>\n");
    if let Some(f) = &s.finding {
        let _ = writeln!(
            o,
            "<p><b>{}</b> — {}</p>",
            escape(&f.action),
            escape(&compact_numbers(&f.evidence))
        );
    }
    px4_lines(o, r, s);
    component_table(o, s);
    o.push_str("<div class=\"row\">");
    let axis = axis.for_sensor(&s.name);
    let scale = series_scale(&s.plot, s.nis.target);
    figure(
        o,
        &nis_series_svg("NIS over time", &s.plot, s.nis.target, &scale, &axis),
        &series_caption(r, s, &scale, &axis),
    );
    let unit = innovation_unit(s);
    if let Some((svg, summary)) = innovation_svg("innovation and ±√S", &s.plot, &axis, unit) {
        figure(o, &svg, &innovation_caption(s, &summary, unit, &axis));
    }
    match &s.plot.histogram {
        Some(h) => figure(
            o,
            &nis_histogram_svg("NIS distribution", h),
            &histogram_caption(s),
        ),
        None => o.push_str("<p>No histogram: no update was kept for one.</p>"),
    }
    if s.whiteness.is_empty() {
        o.push_str("<p>No autocorrelation: the log gives this sensor's NIS without its innovations, or too few updates in a row.</p>");
    } else {
        figure(
            o,
            &nis_whiteness_svg("innovation autocorrelation", &s.whiteness),
            &whiteness_caption(r, s),
        );
    }
    o.push_str("</div></section>\n");
}

/// A self-contained HTML report of a field log.
pub fn nis_html(report: &NisReport) -> String {
    let r = report;
    let mut o = String::new();
    let names: Vec<&str> = r
        .sources
        .iter()
        .map(|s| {
            std::path::Path::new(&s.path)
                .file_name()
                .and_then(|n| n.to_str())
                .unwrap_or(&s.path)
        })
        .collect();
    let title = if names.is_empty() {
        "autotune nis".to_string()
    } else {
        format!("autotune nis: {}", names.join(", "))
    };
    head_styled(&mut o, &title, NIS_STYLE);
    let _ = writeln!(o, "<h1>{}</h1>", escape(&title));
    let _ = writeln!(
        o,
        "<p class=\"verdict\">{}</p>",
        escape(&capitalized(&nis_verdict_line(r)))
    );
    warnings(&mut o, r);
    let _ = writeln!(o, "<p>{}.</p>", escape(&capitalized(&nis_gate_text(r))));
    sources(&mut o, r);
    o.push_str("<h2>Sensors</h2>\n");
    if r.sensors.is_empty() {
        o.push_str("<p>No sensor has an update in the log.</p>\n");
    } else {
        summary_table(&mut o, r);
    }
    not_fused(&mut o, r);
    overall(&mut o, r);
    advice(&mut o, r);
    px4::section(&mut o, r);
    let axis = time_axis(r);
    for (i, s) in r.sensors.iter().enumerate() {
        sensor_section(&mut o, r, &axis, i, s);
    }
    let _ = writeln!(
        o,
        "<p><small>autotune {}</small></p></body></html>",
        env!("CARGO_PKG_VERSION")
    );
    o
}

fn capitalized(s: &str) -> String {
    let mut c = s.chars();
    c.next()
        .map_or(String::new(), |f| f.to_uppercase().chain(c).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fieldlog::{NisAnalyzer, NisSettings, SensorInfo, Update};

    /// A log of `sensors` sensors: the first with two white components, the others with a
    /// NIS alone; `scale` multiplies every NIS.
    fn report(sensors: usize, updates: usize, scale: f64) -> NisReport {
        let mut a = NisAnalyzer::new(NisSettings::default());
        for k in 0..sensors {
            let components = if k == 0 {
                vec!["x".to_string(), "y".to_string()]
            } else {
                Vec::new()
            };
            let i = a
                .sensor(SensorInfo {
                    name: format!("s<{k}>"),
                    components,
                    group: String::new(),
                })
                .unwrap();
            for n in 0..updates {
                let u = [
                    ((n * 7 + k) % 5) as f64 * 0.6 - 1.2,
                    ((n * 3) % 7) as f64 * 0.4 - 1.2,
                ];
                let nis = scale * (u[0] * u[0] + if k == 0 { u[1] * u[1] } else { 0.0 });
                a.push(
                    i,
                    Update {
                        time: n as f64 * 0.1,
                        nis,
                        dof: if k == 0 { 2 } else { 1 },
                        u: (k == 0).then(|| u.iter().map(|x| x * scale.sqrt()).collect()),
                        sd: None,
                    },
                )
                .expect("a valid update");
            }
        }
        a.report()
    }

    #[test]
    fn one_section_per_sensor_and_an_svg_per_plot() {
        let r = report(3, 300, 1.0);
        let html = nis_html(&r);
        assert_eq!(html.matches("<section id=\"sensor-").count(), 3);
        // Three plots for the sensor with components, two for the NIS-only ones.
        assert_eq!(html.matches("<svg").count(), 3 + 2 + 2);
        assert!(!html.contains("plot unavailable"));
        assert!(!html.contains("NaN"));
        assert!(html.contains("s&lt;0&gt;") && !html.contains("s<0>"));
        assert!(html.ends_with("</body></html>\n"));
    }

    #[test]
    fn a_sensor_without_a_mean_or_histogram_still_reports() {
        let mut r = report(2, 80, 1e-6);
        r.sensors[0].nis.mean = f64::NAN;
        r.sensors[0].nis.target = f64::NAN;
        r.sensors[0].nis.interval.lower = f64::NAN;
        r.sensors[0].plot.histogram = None;
        r.sensors[1].plot.series.clear();
        r.sensors[1].plot.outliers.push((f64::NAN, f64::INFINITY));
        let html = nis_html(&r);
        assert_eq!(html.matches("<section id=\"sensor-").count(), 2);
        assert!(html.contains("No histogram"));
        assert!(!html.contains("NaN"));
        // The tiny NIS turn the time plot logarithmic.
        assert!(html.contains("Logarithmic axis"));
        assert!(html.ends_with("</body></html>\n"));
        let empty = nis_html(&report(0, 0, 1.0));
        assert!(empty.contains("No sensor has an update"));
    }
}
