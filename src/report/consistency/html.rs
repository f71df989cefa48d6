//! Consistency reports in HTML, as the check's and the tune's pages show them: the
//! statistics table, the components, the plots of each statistic over time.

use std::fmt::Write;

use crate::report::consistency::cells::StatCells;
use crate::report::consistency::plots::{components_svg, statistic_svg};
use crate::report::html::{escape, figure};
use crate::report::svg::whiteness_svg;
use crate::stats::{ConsistencyReport, StatisticSummary, chi2_average_interval};

fn stat_rows(o: &mut String, label: &str, s: &StatisticSummary) {
    let c = StatCells::of(s);
    let _ = writeln!(
        o,
        "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
        escape(label),
        c.average,
        c.target,
        c.interval,
        c.in_bounds,
        c.verdict
    );
}

pub(in crate::report) fn stats_table(o: &mut String, reports: &[(&str, &ConsistencyReport)]) {
    o.push_str("<table><tr><th>filter / statistic</th><th>time average</th><th>target</th><th>gate interval</th><th>steps in per-step band</th><th>verdict</th></tr>\n");
    for (name, r) in reports {
        if let Some(n) = &r.nees {
            stat_rows(o, &format!("{name} ANEES"), n);
        }
        stat_rows(o, &format!("{name} ANIS"), &r.nis);
    }
    o.push_str("</table>\n");
    for (name, r) in reports {
        for s in r.nees.iter().chain(std::iter::once(&r.nis)) {
            if let Some(note) = crate::report::consistency::cells::run_spread_note(s) {
                let _ = writeln!(o, "<p>Note ({}): {}.</p>", escape(name), escape(&note));
            }
        }
    }
}

/// Every component's second-moment and zero-mean tests, one row each.
pub(in crate::report) fn components_table(o: &mut String, r: &ConsistencyReport) {
    let comps: Vec<_> = r
        .state_components
        .iter()
        .chain(&r.measurement_components)
        .collect();
    if comps.is_empty() {
        return;
    }
    o.push_str("<h2>Components</h2><table><tr><th>kind</th><th>component</th><th>e²/P or ν²/S</th><th>interval</th><th>verdict</th><th>mean e/√P or ν/√S</th><th>z</th><th>zero mean</th></tr>\n");
    for c in comps {
        let (value, interval) = crate::report::consistency::cells::component_cells(c);
        let mut class = Vec::new();
        if matches!(
            c.verdict,
            crate::stats::Verdict::Overconfident | crate::stats::Verdict::Underconfident
        ) {
            class.push("off");
        }
        if c.mean_verdict == crate::stats::Verdict::Biased {
            class.push("biased");
        }
        let (mean, z) = crate::report::consistency::cells::mean_cells(c);
        let _ = writeln!(
            o,
            "<tr class=\"{}\"><td>{}</td><td><code>{}</code></td><td class=\"num v\">{value}</td><td>{interval}</td><td class=\"v\">{}</td><td class=\"num m\">{mean}</td><td class=\"num m\">{z}</td><td class=\"m\">{}</td></tr>",
            class.join(" "),
            c.kind,
            escape(&c.name),
            c.verdict.label(),
            if c.mean_z.is_finite() {
                c.mean_verdict.label()
            } else {
                "–"
            }
        );
    }
    o.push_str("</table>\n");
}

/// Steps per plotted point: 1 while the per-step averages over the runs are readable, and
/// blocks of steps when few runs cover many steps (one record of 5 000 steps is 5 000
/// single χ² draws, a black band on a plot 500 pixels wide).
fn block_len(runs: usize, steps: usize) -> usize {
    if runs >= 20 || steps <= 400 {
        1
    } else {
        steps.div_ceil(100)
    }
}

/// `s` averaged over consecutive blocks of `block` steps, each block at its middle step
/// with its own (1 − α) interval: the average of the block's χ² variables (their degrees
/// of freedom add up over the block's steps and `runs` runs).
fn block_averages(s: &StatisticSummary, runs: usize, alpha: f64, block: usize) -> StatisticSummary {
    let steps = s.per_step.len();
    let mut out = s.clone();
    for v in [
        &mut out.per_step,
        &mut out.per_step_lower,
        &mut out.per_step_upper,
        &mut out.per_step_target,
    ] {
        v.iter_mut().for_each(|x| *x = None);
    }
    for start in (0..steps).step_by(block.max(1)) {
        let end = (start + block).min(steps);
        let (mut sum, mut dof, mut count) = (0.0, 0.0, 0usize);
        for k in start..end {
            if let (Some(v), Some(t)) = (s.per_step[k], s.per_step_target[k]) {
                sum += v;
                dof += t;
                count += 1;
            }
        }
        if count == 0 {
            continue;
        }
        let n = (count * runs.max(1)) as f64;
        let iv = chi2_average_interval(alpha, dof * runs.max(1) as f64, n);
        let mid = (start + end - 1) / 2;
        out.per_step[mid] = Some(sum / count as f64);
        out.per_step_lower[mid] = Some(iv.lower);
        out.per_step_upper[mid] = Some(iv.upper);
        out.per_step_target[mid] = Some(dof / count as f64);
    }
    out
}

/// Plots of one consistency report, side by side with another's where given.
pub(in crate::report) fn plots(o: &mut String, reports: &[(&str, &ConsistencyReport)]) {
    let stats: Vec<(&str, Vec<(&str, &StatisticSummary)>)> = vec![
        (
            "ANEES",
            reports
                .iter()
                .filter_map(|(n, r)| r.nees.as_ref().map(|s| (*n, s)))
                .collect(),
        ),
        ("ANIS", reports.iter().map(|(n, r)| (*n, &r.nis)).collect()),
    ];
    for (name, series) in stats {
        if series.is_empty() {
            continue;
        }
        let _ = writeln!(o, "<h2>{name} over time</h2><div class=\"row\">");
        let (runs, alpha) = (reports[0].1.runs, reports[0].1.alpha);
        for (label, s) in series {
            let block = block_len(runs, s.per_step.len());
            if block == 1 {
                figure(
                    o,
                    &statistic_svg(&format!("{name}_k, {label} filter"), s),
                    &format!(
                        "{label}: {name}_k averaged over {runs} runs at each step; grey band: per-step (1-α) chi-square interval; dashed: DOF target; crosses: steps outside the band."
                    ),
                );
            } else {
                figure(
                    o,
                    &statistic_svg(
                        &format!("{name}, {label} filter, blocks of {block} steps"),
                        &block_averages(s, runs, alpha, block),
                    ),
                    &format!(
                        "{label}: {name} averaged over {runs} run(s) and blocks of {block} steps, at each block's middle step; grey band: each block's (1-α) chi-square interval; dashed: DOF target; crosses: blocks outside their band."
                    ),
                );
            }
        }
        o.push_str("</div>\n");
    }
    o.push_str("<h2>Per-component normalized errors</h2><div class=\"row\">");
    for (label, r) in reports {
        let comps: Vec<_> = r
            .state_components
            .iter()
            .chain(&r.measurement_components)
            .cloned()
            .collect();
        figure(
            o,
            &components_svg(&format!("components, {label} filter"), &comps),
            &format!(
                "{label}: mean e_j²/P_jj per state and ν_j²/S_jj per measurement component; bars with their interval around the target 1."
            ),
        );
    }
    o.push_str("</div>\n<h2>Innovation whiteness</h2><div class=\"row\">");
    for (label, r) in reports {
        figure(
            o,
            &whiteness_svg(
                &format!("innovation autocorrelation, {label} filter"),
                &r.whiteness,
            ),
            &format!(
                "{label}: normalized autocorrelation of ν_j/√S_jj by lag; a consistent filter's innovations are white and stay inside the grey band."
            ),
        );
    }
    o.push_str("</div>\n");
}
