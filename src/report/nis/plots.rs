//! The plots of `autotune nis`: a sensor's NIS over time, its innovation in its ±√S band,
//! its histogram against the χ² density and its innovations' autocorrelation.
//!
//! Same conventions as [`super::plots`]: black and greys, told apart by fill, dash and
//! marker; a plot that cannot be drawn becomes a note, never a lost report. The time plots
//! share one x axis ([`TimeAxis`]: the log's own time origin and its events as vertical
//! lines), and every legend sits in a strip under its plot, never over the data.

use std::collections::HashSet;

use plotters::coord::Shift;
use plotters::coord::ranged1d::Ranged;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use statrs::distribution::{ChiSquared, Continuous};

use crate::fieldlog::{Histogram, SensorPlot};
use crate::report::svg::{BAND, Drawn, FONT, MID, chart_builder, render_sized};

mod innovation;
mod legend;
mod markers;
mod scale;
mod whiteness;

use legend::{LegendItem, Swatch, draw_legend, strip_height};
use markers::draw_events;
use scale::finite_positive;

pub(super) use innovation::{InnovationSummary, innovation_svg};
pub(super) use markers::TimeAxis;
pub(super) use scale::{SeriesScale, series_scale};
pub(super) use whiteness::nis_whiteness_svg;

/// Size of each per-sensor plot: three fit side by side in the report's width.
pub(super) const NIS_SIZE: (u32, u32) = (440, 300);
/// Grey of the per-update points, lighter than the lines drawn over them.
const POINT: RGBColor = RGBColor(140, 140, 140);
/// Grid on which the per-update points are thinned: one point per cell is drawn, and a
/// cell is about two pixels of the plot area, a dot's width.
const CELLS: (f64, f64) = (NIS_SIZE.0 as f64 * 0.42, NIS_SIZE.1 as f64 * 0.37);

/// The points and lines of a NIS-over-time plot, in display values.
struct SeriesLayers {
    t: (f64, f64),
    points: Vec<(f64, f64)>,
    averages: Vec<Vec<(f64, f64)>>,
    bands: Vec<Vec<(f64, f64)>>,
    outliers: Vec<(f64, f64)>,
    target: Option<f64>,
}

/// The time range of a plot: its points' times widened to the axis' events.
fn time_range(times: impl Iterator<Item = f64>, axis: &TimeAxis) -> (f64, f64) {
    let (t0, t1) = times
        .filter(|t| t.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), t| {
            (a.min(t), b.max(t))
        });
    if t0.is_finite() {
        axis.span((t0, t1))
    } else if axis.events.is_empty() {
        (0.0, 1.0)
    } else {
        axis.span((axis.events[0].time, axis.events[0].time))
    }
}

impl SeriesLayers {
    fn new(plot: &SensorPlot, target: f64, scale: &SeriesScale, axis: &TimeAxis) -> Self {
        let y = |v: f64| scale.display(v);
        let times = plot
            .series
            .iter()
            .map(|p| p.t)
            .chain(plot.outliers.iter().map(|o| o.0));
        let t = time_range(times, axis);
        let (ylo, yhi) = if scale.log {
            (scale.floor.ln(), scale.top.ln())
        } else {
            (0.0, scale.top)
        };
        // The cell of a point on a grid `fine` times the dots' grid.
        let cell_at = |fine: f64, tv: f64, v: f64| {
            let yv = if scale.log { v.ln() } else { v };
            (
                ((tv - t.0) / (t.1 - t.0) * CELLS.0 * fine) as i64,
                ((yv - ylo) / (yhi - ylo) * CELLS.1 * fine) as i64,
            )
        };
        let cell = |tv: f64, v: f64| cell_at(1.0, tv, v);
        let pixel = |p: &(f64, f64)| cell_at(2.0, p.0, p.1);
        let mut seen = HashSet::new();
        let points = plot
            .series
            .iter()
            .filter(|p| p.t.is_finite() && p.nis.is_finite())
            .map(|p| (p.t, y(p.nis)))
            .filter(|&(tv, v)| seen.insert(cell(tv, v)))
            .collect();
        // Runs of consecutive points with a window average (and with its interval).
        let mut averages: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
        let mut bands: Vec<Vec<(f64, f64, f64)>> = vec![Vec::new()];
        for p in plot.series.iter().filter(|p| p.t.is_finite()) {
            match p.window.filter(|w| w.is_finite()) {
                Some(w) => averages.last_mut().expect("one run").push((p.t, y(w))),
                None => averages.push(Vec::new()),
            }
            match (p.lower, p.upper) {
                (Some(l), Some(u)) if l.is_finite() && u.is_finite() => {
                    bands.last_mut().expect("one run").push((p.t, y(l), y(u)));
                }
                _ => bands.push(Vec::new()),
            }
        }
        averages.retain(|a| !a.is_empty());
        let averages = averages.into_iter().map(|a| thin(a, pixel)).collect();
        let bands = bands
            .into_iter()
            .filter(|b| !b.is_empty())
            .map(|b| {
                let mut poly = thin(b.iter().map(|p| (p.0, p.2)).collect(), pixel);
                poly.extend(thin(b.iter().rev().map(|p| (p.0, p.1)).collect(), pixel));
                poly
            })
            .collect();
        let outliers = plot
            .outliers
            .iter()
            .filter(|o| o.0.is_finite() && o.1.is_finite())
            .map(|o| (o.0, y(o.1)))
            .collect();
        SeriesLayers {
            t,
            points,
            averages,
            bands,
            outliers,
            target: finite_positive(target).map(y),
        }
    }

    /// The legend of the layers drawn, then of the axis' events.
    fn legend(&self, axis: &TimeAxis) -> Vec<LegendItem> {
        let mut items = Vec::new();
        if !self.bands.is_empty() {
            items.push(LegendItem::new("window interval", Swatch::Fill(BAND)));
        }
        items.push(LegendItem::new("NIS of an update", Swatch::Dot(POINT)));
        if !self.averages.is_empty() {
            items.push(LegendItem::new("window average", Swatch::Line(BLACK, 2)));
        }
        if self.target.is_some() {
            items.push(LegendItem::new("expected", Swatch::Dashed(MID, 6, 4, 2)));
        }
        if !self.outliers.is_empty() {
            items.push(LegendItem::new("outlier", Swatch::Triangle(BLACK)));
        }
        items.extend(axis.legend());
        items
    }
}

/// The vertices of a line that fall on a new pixel (`pixel` of each), and its last one.
fn thin(line: Vec<(f64, f64)>, pixel: impl Fn(&(f64, f64)) -> (i64, i64)) -> Vec<(f64, f64)> {
    let Some(&last) = line.last() else {
        return line;
    };
    let mut kept: Vec<(f64, f64)> = Vec::with_capacity(line.len());
    for p in line {
        if kept.last().is_none_or(|k| pixel(k) != pixel(&p)) {
            kept.push(p);
        }
    }
    if kept.last() != Some(&last) {
        kept.push(last);
    }
    kept
}

/// Draws a plot of `NIS_SIZE` with `items` as its legend in a strip under it.
fn render_with_legend(
    title: &str,
    items: &[LegendItem],
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> Drawn,
) -> String {
    let strip = strip_height(items, NIS_SIZE.0);
    render_sized(title, (NIS_SIZE.0, NIS_SIZE.1 + strip), |root| {
        let (plot, legend) = root.split_vertically(NIS_SIZE.1);
        draw(&plot)?;
        draw_legend(&legend, items)
    })
}

/// The x-axis tick labels of a time span: whole seconds once it spans ten.
fn time_decimals((t0, t1): (f64, f64)) -> usize {
    if t1 - t0 >= 10.0 { 0 } else { 1 }
}

/// A sensor's NIS over time: each update as a small grey point, the moving-window average
/// (black line) in its interval (grey band), the target (dashed), the outliers (triangles)
/// and the axis' events (vertical lines), on the y axis `scale` gives; the legend under it.
pub(super) fn nis_series_svg(
    title: &str,
    plot: &SensorPlot,
    target: f64,
    scale: &SeriesScale,
    axis: &TimeAxis,
) -> String {
    let layers = SeriesLayers::new(plot, target, scale, axis);
    render_with_legend(title, &layers.legend(axis), |root| {
        draw_nis_series(root, title, &layers, scale, axis)
    })
}

fn draw_nis_series(
    root: &DrawingArea<SVGBackend<'_>, Shift>,
    title: &str,
    layers: &SeriesLayers,
    scale: &SeriesScale,
    axis: &TimeAxis,
) -> Drawn {
    let (t0, t1) = layers.t;
    let decimals = time_decimals(layers.t);
    let x_fmt = move |x: &f64| format!("{x:.decimals$}");
    let mut builder = chart_builder(root, title, 55);
    if scale.log {
        let mut chart = builder.build_cartesian_2d(t0..t1, (scale.floor..scale.top).log_scale())?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(axis.label.as_str())
            .x_label_formatter(&x_fmt)
            .y_desc("NIS (log scale)")
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .axis_desc_style((FONT, 13))
            .draw()?;
        draw_nis_layers(&mut chart, layers, axis, (scale.floor, scale.top))
    } else {
        let mut chart = builder.build_cartesian_2d(t0..t1, 0.0..scale.top)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(axis.label.as_str())
            .x_label_formatter(&x_fmt)
            .y_desc("NIS")
            .axis_desc_style((FONT, 13))
            .draw()?;
        draw_nis_layers(&mut chart, layers, axis, (0.0, scale.top))
    }
}

/// The layers over the axis' events (from `y.0` to `y.1`), drawn over the band so that the
/// band does not hide them and under the points so that they hide no update.
fn draw_nis_layers<'a, Y: Ranged<ValueType = f64>>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<RangedCoordf64, Y>>,
    layers: &SeriesLayers,
    axis: &TimeAxis,
    y: (f64, f64),
) -> Drawn {
    chart.draw_series(
        layers
            .bands
            .iter()
            .map(|b| Polygon::new(b.clone(), BAND.filled())),
    )?;
    draw_events(chart, axis, y)?;
    chart.draw_series(
        layers
            .points
            .iter()
            .map(|&p| Circle::new(p, 1, POINT.filled())),
    )?;
    chart.draw_series(
        layers
            .averages
            .iter()
            .map(|a| PathElement::new(a.clone(), BLACK.stroke_width(2))),
    )?;
    if let Some(target) = layers.target {
        chart.draw_series(DashedLineSeries::new(
            vec![(layers.t.0, target), (layers.t.1, target)],
            6,
            4,
            MID.stroke_width(2),
        ))?;
    }
    chart.draw_series(
        layers
            .outliers
            .iter()
            .map(|&p| TriangleMarker::new(p, 5, BLACK.filled())),
    )?;
    Ok(())
}

/// Samples of the χ² density drawn across the histogram.
const CURVE_POINTS: usize = 300;

/// The histogram of a sensor's NIS as a density (bars) against the `χ²(m)` density (line).
pub(super) fn nis_histogram_svg(title: &str, h: &Histogram) -> String {
    let items = [
        LegendItem::new(
            format!("updates ({})", h.counts.iter().sum::<u64>() + h.above),
            Swatch::Fill(BAND),
        ),
        LegendItem::new(format!("χ²({}) density", h.dof), Swatch::Line(BLACK, 2)),
    ];
    render_with_legend(title, &items, |root| draw_histogram(root, title, h))
}

fn draw_histogram(root: &DrawingArea<SVGBackend<'_>, Shift>, title: &str, h: &Histogram) -> Drawn {
    if !(h.top.is_finite() && h.top > 0.0) || h.counts.is_empty() {
        return Err(format!("no range for the histogram (top {})", h.top).into());
    }
    let width = h.top / h.counts.len() as f64;
    let total = (h.counts.iter().sum::<u64>() + h.above) as f64;
    let density: Vec<f64> = h
        .counts
        .iter()
        .map(|&c| {
            if total > 0.0 {
                c as f64 / (total * width)
            } else {
                0.0
            }
        })
        .collect();
    let chi2 = ChiSquared::new(h.dof as f64)?;
    let curve: Vec<(f64, f64)> = (1..=CURVE_POINTS)
        .map(|i| {
            let x = h.top * i as f64 / CURVE_POINTS as f64;
            (x, chi2.pdf(x))
        })
        .collect();
    // χ²(1)'s density is unbounded at 0: scale to the bars and to the curve from the middle
    // of the first bin on, and let the curve leave through the top.
    let curve_top = curve
        .iter()
        .filter(|p| p.0 >= width / 2.0)
        .map(|p| p.1)
        .fold(0.0_f64, f64::max);
    let ymax = density.iter().copied().fold(curve_top, f64::max).max(1e-9) * 1.05;
    let mut chart = chart_builder(root, title, 55).build_cartesian_2d(0.0..h.top, 0.0..ymax)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(format!("NIS (m = {})", h.dof))
        .y_desc("density")
        .axis_desc_style((FONT, 13))
        .draw()?;
    let bar = |i: usize, d: f64| {
        let x = i as f64 * width;
        [(x, 0.0), (x + width, d)]
    };
    chart.draw_series(
        density
            .iter()
            .enumerate()
            .map(|(i, &d)| Rectangle::new(bar(i, d), BAND.filled())),
    )?;
    chart.draw_series(
        density
            .iter()
            .enumerate()
            .filter(|(_, d)| **d > 0.0)
            .map(|(i, &d)| Rectangle::new(bar(i, d), MID.stroke_width(1))),
    )?;
    chart.draw_series(LineSeries::new(
        curve.into_iter().skip_while(|p| p.1 > ymax),
        BLACK.stroke_width(2),
    ))?;
    Ok(())
}
