//! The check and tune reports' plots: a statistic over time in its band, per-component
//! ratios against their intervals, the objective over a search.

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::report::svg::{BAND, Drawn, FONT, MID, chart_builder, legend, render};
use crate::stats::{ComponentStat, StatisticSummary};

/// A per-step statistic (ANEES_k or ANIS_k) against time with its [r1, r2] band, the DOF
/// target, and the steps outside the band marked.
pub fn statistic_svg(title: &str, s: &StatisticSummary) -> String {
    render(title, |root| draw_statistic(root, title, s))
}

fn draw_statistic(
    root: &DrawingArea<SVGBackend<'_>, Shift>,
    title: &str,
    s: &StatisticSummary,
) -> Drawn {
    let steps = s.per_step.len().max(1);
    let pts: Vec<(f64, f64, f64, f64, f64)> = (0..s.per_step.len())
        .filter_map(|k| {
            Some((
                (k + 1) as f64,
                s.per_step[k]?,
                s.per_step_lower[k]?,
                s.per_step_upper[k]?,
                s.per_step_target[k]?,
            ))
        })
        .collect();
    let top_band = pts.iter().map(|p| p.3).fold(0.0_f64, f64::max);
    let top_data = pts.iter().map(|p| p.1).fold(0.0_f64, f64::max);
    let target = if s.target.is_finite() { s.target } else { 1.0 };
    // Show the data, but keep the band readable when a filter is wildly off.
    let ymax = (top_data.max(top_band) * 1.05)
        .min((top_band * 1.05).max(4.0 * target))
        .max(1e-9);
    let mut chart = chart_builder(root, title, 60)
        .build_cartesian_2d(0.5f64..steps as f64 + 0.5, 0f64..ymax)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("time step k")
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_desc(format!("A{}_k (dimensionless)", s.name))
        .axis_desc_style((FONT, 14))
        .draw()?;
    let mut band: Vec<(f64, f64)> = pts.iter().map(|p| (p.0, p.3.min(ymax))).collect();
    band.extend(pts.iter().rev().map(|p| (p.0, p.2.min(ymax))));
    chart
        .draw_series(std::iter::once(Polygon::new(band, BAND.filled())))?
        .label("per-step interval [r1, r2]")
        .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 16, y + 5)], BAND.filled()));
    chart
        .draw_series(DashedLineSeries::new(
            pts.iter().map(|p| (p.0, p.4)),
            6,
            4,
            MID.stroke_width(2),
        ))?
        .label(format!("DOF target {target:.3}"))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], MID.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(
            pts.iter().map(|p| (p.0, p.1.min(ymax))),
            BLACK.stroke_width(1),
        ))?
        .label(format!("A{}_k", s.name))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(1)));
    let outside: Vec<(f64, f64)> = pts
        .iter()
        .filter(|p| p.1 < p.2 || p.1 > p.3)
        .map(|p| (p.0, p.1.min(ymax)))
        .collect();
    chart
        .draw_series(
            outside
                .iter()
                .map(|&p| Cross::new(p, 4, BLACK.stroke_width(1))),
        )?
        .label(format!("outside the interval ({})", outside.len()))
        .legend(|(x, y)| Cross::new((x + 8, y), 4, BLACK.stroke_width(1)));
    legend(&mut chart, SeriesLabelPosition::LowerRight)
}

/// Per-component normalized errors as bars against the target 1, each with its interval.
pub fn components_svg(title: &str, comps: &[ComponentStat]) -> String {
    render(title, |root| draw_components(root, title, comps))
}

fn draw_components(
    root: &DrawingArea<SVGBackend<'_>, Shift>,
    title: &str,
    comps: &[ComponentStat],
) -> Drawn {
    let n = comps.len().max(1);
    let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
    let ymax = comps
        .iter()
        .map(|c| finite(c.value).max(finite(c.interval.upper)))
        .fold(1.5_f64, f64::max)
        * 1.1;
    let names: Vec<String> = comps
        .iter()
        .map(|c| {
            format!(
                "{} ({})",
                c.name,
                if c.kind == "state" { "e²/P" } else { "ν²/S" }
            )
        })
        .collect();
    let mut chart =
        chart_builder(root, title, 60).build_cartesian_2d(-0.5f64..n as f64 - 0.5, 0f64..ymax)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(n)
        .x_label_formatter(&|x| {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < names.len() {
                names[i as usize].clone()
            } else {
                String::new()
            }
        })
        .x_desc("component")
        .y_desc("mean normalized squared error (target 1)")
        .axis_desc_style((FONT, 14))
        .draw()?;
    chart
        .draw_series(comps.iter().enumerate().map(|(i, c)| {
            let x = i as f64;
            Rectangle::new(
                [(x - 0.3, 0.0), (x + 0.3, finite(c.value).min(ymax))],
                BAND.filled(),
            )
        }))?
        .label("average over runs and steps")
        .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 16, y + 5)], BAND.filled()));
    chart.draw_series(comps.iter().enumerate().map(|(i, c)| {
        let x = i as f64;
        Rectangle::new(
            [(x - 0.3, 0.0), (x + 0.3, finite(c.value).min(ymax))],
            BLACK.stroke_width(1),
        )
    }))?;
    chart
        .draw_series(
            comps
                .iter()
                .enumerate()
                .filter(|(_, c)| c.interval.lower.is_finite() && c.interval.upper.is_finite())
                .map(|(i, c)| {
                    ErrorBar::new_vertical(
                        i as f64,
                        c.interval.lower.max(0.0),
                        1.0,
                        c.interval.upper.min(ymax),
                        BLACK.stroke_width(2),
                        12,
                    )
                }),
        )?
        .label("interval around 1 (1-α, from run-to-run spread)")
        .legend(|(x, y)| {
            PathElement::new(vec![(x + 8, y - 6), (x + 8, y + 6)], BLACK.stroke_width(2))
        });
    chart
        .draw_series(DashedLineSeries::new(
            vec![(-0.5, 1.0), (n as f64 - 0.5, 1.0)],
            6,
            4,
            MID.stroke_width(2),
        ))?
        .label("target 1")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], MID.stroke_width(2)));
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}

/// The best objective value against evaluations, on a log scale.
pub fn objective_svg(title: &str, history: &[f64]) -> String {
    render(title, |root| draw_objective(root, title, history))
}

fn draw_objective(
    root: &DrawingArea<SVGBackend<'_>, Shift>,
    title: &str,
    history: &[f64],
) -> Drawn {
    let pts: Vec<(f64, f64)> = history
        .iter()
        .enumerate()
        .filter(|(_, v)| v.is_finite() && **v > 0.0)
        .map(|(i, v)| ((i + 1) as f64, *v))
        .collect();
    let lo = pts
        .iter()
        .map(|p| p.1)
        .fold(f64::INFINITY, f64::min)
        .min(1.0);
    let hi = pts
        .iter()
        .map(|p| p.1)
        .fold(0.0_f64, f64::max)
        .max(lo * 10.0);
    let n = history.len().max(2) as f64;
    let mut chart = chart_builder(root, title, 70)
        .build_cartesian_2d(1f64..n, (lo * 0.5..hi * 2.0).log_scale())?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("evaluations")
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_desc("best objective J (dimensionless, log)")
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .axis_desc_style((FONT, 14))
        .draw()?;
    chart
        .draw_series(LineSeries::new(pts, BLACK.stroke_width(2)))?
        .label("best so far")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(2)));
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}
