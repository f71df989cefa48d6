//! A channel's innovation ν over time inside its own ±√S and ±2√S bands: the plot an EKF2
//! engineer reads first. A consistent filter keeps about 68% of the points inside ±√S and
//! 95% inside ±2√S, centred on zero; a bias shows as a cloud off zero, a too-small S as
//! points spilling out of the bands, a too-large S as points hugging zero.

use std::collections::HashSet;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::legend::{LegendItem, Swatch};
use super::markers::{TimeAxis, draw_events};
use super::{CELLS, render_with_legend, thin, time_decimals, time_range};
use crate::fieldlog::SensorPlot;
use crate::report::svg::{BAND, Drawn, FONT, MID, chart_builder};

/// The ±2√S band, lighter than the ±√S one drawn over it.
const BAND2: RGBColor = RGBColor(235, 235, 235);
/// Quantile of |ν| the y axis reaches at least (besides 2√S): a few far points do not
/// squash the rest; they are drawn at the edge and counted.
const REACH_QUANTILE: f64 = 0.99;
/// Quantile of 2√S the y axis reaches at least, with the margin below.
const BAND_QUANTILE: f64 = 0.9;
const BAND_MARGIN: f64 = 1.25;

/// What the innovation plot shows, for its caption.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(in crate::report) struct InnovationSummary {
    /// Updates with an innovation in the plot's series.
    pub points: usize,
    /// Of them, inside ±√S.
    pub inside_1: usize,
    /// Of them, inside ±2√S.
    pub inside_2: usize,
    /// Beyond the y axis' reach, drawn at its edge.
    pub clipped: usize,
    /// Updates whose ±2√S band is wider than the y axis (cut at its edge).
    pub band_clipped: usize,
    /// The y axis' half-range, in the measurement's units.
    pub reach: f64,
}

/// The layers of the plot, in display values.
struct Layers {
    t: (f64, f64),
    reach: f64,
    points: Vec<(f64, f64)>,
    band1: Vec<Vec<(f64, f64)>>,
    band2: Vec<Vec<(f64, f64)>>,
}

/// `(t, ν, √S)` of the series points that have a finite innovation and a positive √S.
fn samples(plot: &SensorPlot) -> Vec<(f64, f64, f64)> {
    plot.series
        .iter()
        .filter_map(|p| p.innovation.map(|(nu, sd)| (p.t, nu, sd)))
        .filter(|&(t, nu, sd)| t.is_finite() && nu.is_finite() && sd.is_finite() && sd > 0.0)
        .collect()
}

fn layers(s: &[(f64, f64, f64)], axis: &TimeAxis) -> (Layers, InnovationSummary) {
    let t = time_range(s.iter().map(|p| p.0), axis);
    let quantile = |mut v: Vec<f64>, q: f64| {
        v.sort_by(f64::total_cmp);
        v.get(((v.len() as f64 * q) as usize).min(v.len().saturating_sub(1)))
            .copied()
            .unwrap_or(0.0)
    };
    let q = quantile(s.iter().map(|p| p.1.abs()).collect(), REACH_QUANTILE);
    // The band's usual width, not its widest: S starts large while the filter converges,
    // and those first updates must not flatten the rest (their band is clipped at the edge).
    let band = quantile(s.iter().map(|p| 2.0 * p.2).collect(), BAND_QUANTILE);
    let reach = match (BAND_MARGIN * band).max(q) * 1.08 {
        r if r.is_finite() && r > 0.0 => r,
        _ => 1.0,
    };
    let clip = |v: f64| v.clamp(-reach, reach);
    let cell_at = |fine: f64, tv: f64, v: f64| {
        (
            ((tv - t.0) / (t.1 - t.0) * CELLS.0 * fine) as i64,
            ((v + reach) / (2.0 * reach) * CELLS.1 * fine) as i64,
        )
    };
    let pixel = |p: &(f64, f64)| cell_at(2.0, p.0, p.1);
    let mut seen = HashSet::new();
    let points = s
        .iter()
        .map(|p| (p.0, clip(p.1)))
        .filter(|&(tv, v)| seen.insert(cell_at(1.0, tv, v)))
        .collect();
    let band = |k: f64| {
        let mut upper: Vec<(f64, f64)> = s.iter().map(|p| (p.0, clip(k * p.2))).collect();
        let lower: Vec<(f64, f64)> = s.iter().rev().map(|p| (p.0, clip(-k * p.2))).collect();
        upper = thin(upper, pixel);
        upper.extend(thin(lower, pixel));
        if upper.is_empty() {
            Vec::new()
        } else {
            vec![upper]
        }
    };
    let summary = InnovationSummary {
        points: s.len(),
        inside_1: s.iter().filter(|p| p.1.abs() <= p.2).count(),
        inside_2: s.iter().filter(|p| p.1.abs() <= 2.0 * p.2).count(),
        clipped: s.iter().filter(|p| p.1.abs() > reach).count(),
        band_clipped: s.iter().filter(|p| 2.0 * p.2 > reach).count(),
        reach,
    };
    let layers = Layers {
        t,
        reach,
        points,
        band1: band(1.0),
        band2: band(2.0),
    };
    (layers, summary)
}

/// The innovation of a channel's first component over time, in `unit`, with its ±√S band
/// and, lighter, ±2√S, the axis' events and the legend under it; None when the series
/// carries no innovation (a log giving the NIS alone).
pub(in crate::report) fn innovation_svg(
    title: &str,
    plot: &SensorPlot,
    axis: &TimeAxis,
    unit: &str,
) -> Option<(String, InnovationSummary)> {
    let s = samples(plot);
    if s.is_empty() {
        return None;
    }
    let (layers, summary) = layers(&s, axis);
    let mut items = vec![
        LegendItem::new("±2√S", Swatch::Fill(BAND2)),
        LegendItem::new("±√S", Swatch::Fill(BAND)),
        LegendItem::new("innovation ν", Swatch::Dot(BLACK)),
    ];
    items.extend(axis.legend());
    let svg = render_with_legend(title, &items, |root| draw(root, title, &layers, axis, unit));
    Some((svg, summary))
}

fn draw(
    root: &DrawingArea<SVGBackend<'_>, Shift>,
    title: &str,
    l: &Layers,
    axis: &TimeAxis,
    unit: &str,
) -> Drawn {
    let decimals = time_decimals(l.t);
    let x_fmt = move |x: &f64| format!("{x:.decimals$}");
    // Enough decimals to tell ticks apart at this reach; a tick that rounds to 0 is "0".
    let y_decimals = (1 - l.reach.log10().floor() as i32).max(0) as usize;
    let y_fmt = move |v: &f64| {
        let t = format!("{v:.y_decimals$}");
        if t.trim_start_matches('-')
            .chars()
            .all(|c| c == '0' || c == '.')
        {
            "0".to_string()
        } else {
            t
        }
    };
    let mut chart =
        chart_builder(root, title, 60).build_cartesian_2d(l.t.0..l.t.1, -l.reach..l.reach)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(axis.label.as_str())
        .x_label_formatter(&x_fmt)
        .y_desc(format!("innovation ν ({unit})"))
        .y_label_formatter(&y_fmt)
        .axis_desc_style((FONT, 13))
        .draw()?;
    chart.draw_series(
        l.band2
            .iter()
            .map(|b| Polygon::new(b.clone(), BAND2.filled())),
    )?;
    chart.draw_series(
        l.band1
            .iter()
            .map(|b| Polygon::new(b.clone(), BAND.filled())),
    )?;
    chart.draw_series(std::iter::once(PathElement::new(
        vec![(l.t.0, 0.0), (l.t.1, 0.0)],
        MID.stroke_width(1),
    )))?;
    draw_events(&mut chart, axis, (-l.reach, l.reach))?;
    // Black dots over the grey bands: the NIS plot's grey would vanish in them.
    chart.draw_series(l.points.iter().map(|&p| Circle::new(p, 1, BLACK.filled())))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fieldlog::SeriesPoint;

    fn point(t: f64, nu: f64, sd: f64) -> SeriesPoint {
        SeriesPoint {
            t,
            nis: (nu / sd).powi(2),
            window: None,
            lower: None,
            upper: None,
            innovation: Some((nu, sd)),
        }
    }

    #[test]
    fn the_band_counts_and_the_reach_follow_the_innovations() {
        // ν alternating 0.5, 1.5 and -2.5 times √S = 2: one third in each zone.
        let series: Vec<SeriesPoint> = (0..300)
            .map(|i| {
                let k = [0.5, 1.5, -2.5][i % 3];
                point(i as f64 * 0.1, 2.0 * k, 2.0)
            })
            .collect();
        let plot = SensorPlot {
            series,
            ..SensorPlot::default()
        };
        let (svg, s) = innovation_svg("ν", &plot, &TimeAxis::plain(), "m").expect("a plot");
        assert_eq!((s.points, s.inside_1, s.inside_2), (300, 100, 200));
        // The reach covers the 99% quantile of |ν| (5) with its margin, nothing clipped.
        assert!((s.reach - 5.0 * 1.08).abs() < 1e-9 && s.clipped == 0);
        assert!(svg.contains("innovation ν (m)") && !svg.contains("unavailable"));
        let none = SensorPlot {
            series: vec![SeriesPoint {
                innovation: None,
                ..point(0.0, 1.0, 1.0)
            }],
            ..SensorPlot::default()
        };
        assert!(innovation_svg("ν", &none, &TimeAxis::plain(), "m").is_none());
    }

    #[test]
    fn a_converging_start_does_not_flatten_the_plot() {
        // √S = 10 over the first 2% of updates, then 0.1.
        let series: Vec<SeriesPoint> = (0..500)
            .map(|i| point(i as f64, 0.05, if i < 10 { 10.0 } else { 0.1 }))
            .collect();
        let plot = SensorPlot {
            series,
            ..SensorPlot::default()
        };
        let (_, s) = innovation_svg("ν", &plot, &TimeAxis::plain(), "m").expect("a plot");
        assert!(
            (s.reach - 1.25 * 0.2 * 1.08).abs() < 1e-9,
            "reach {}",
            s.reach
        );
    }

    #[test]
    fn a_far_spike_is_drawn_at_the_edge_and_counted() {
        let mut series: Vec<SeriesPoint> = (0..500)
            .map(|i| point(i as f64, if i % 2 == 0 { 0.3 } else { -0.3 }, 1.0))
            .collect();
        series[7] = point(7.0, 1e6, 1.0);
        let plot = SensorPlot {
            series,
            ..SensorPlot::default()
        };
        let (_, s) = innovation_svg("ν", &plot, &TimeAxis::plain(), "m").expect("a plot");
        assert_eq!(s.clipped, 1);
        assert!(
            s.reach < 3.0,
            "the spike must not set the axis: {}",
            s.reach
        );
    }
}
