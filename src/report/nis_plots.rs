//! The plots of `autotune nis`: a sensor's NIS over time and its histogram against the χ²
//! density (the autocorrelation is [`super::plots::whiteness_svg_sized`]).
//!
//! Same conventions as [`super::plots`]: black and greys, told apart by fill, dash and
//! marker; a plot that cannot be drawn becomes a note, never a lost report.

use std::collections::HashSet;

use plotters::coord::Shift;
use plotters::coord::ranged1d::Ranged;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use statrs::distribution::{ChiSquared, Continuous};

use super::plots::{BAND, Drawn, FONT, MID, chart_builder, legend_sized, render_sized};
use crate::fieldlog::{Histogram, SensorPlot};

mod scale;

use scale::finite_positive;
pub(super) use scale::{SeriesScale, series_scale};

/// Size of each per-sensor plot: three fit side by side in the report's width.
pub(super) const NIS_SIZE: (u32, u32) = (440, 300);
/// Grey of the per-update points, lighter than the lines drawn over them.
const POINT: RGBColor = RGBColor(140, 140, 140);
/// Grid on which the per-update points are thinned: one point per cell is drawn, and a
/// cell is about two pixels of the plot area, a dot's width.
const CELLS: (f64, f64) = (NIS_SIZE.0 as f64 * 0.42, NIS_SIZE.1 as f64 * 0.37);
/// The share of the plot's width and height the legend covers.
const LEGEND: (f64, f64) = (0.45, 0.45);

/// The points and lines of a NIS-over-time plot, in display values.
struct SeriesLayers {
    t: (f64, f64),
    points: Vec<(f64, f64)>,
    averages: Vec<Vec<(f64, f64)>>,
    bands: Vec<Vec<(f64, f64)>>,
    outliers: Vec<(f64, f64)>,
    target: Option<f64>,
    /// Where the legend hides the least.
    corner: SeriesLabelPosition,
}

impl SeriesLayers {
    fn new(plot: &SensorPlot, target: f64, scale: &SeriesScale) -> Self {
        let y = |v: f64| scale.display(v);
        let times = plot
            .series
            .iter()
            .map(|p| p.t)
            .chain(plot.outliers.iter().map(|o| o.0))
            .filter(|t| t.is_finite());
        let (t0, t1) = times.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), t| {
            (a.min(t), b.max(t))
        });
        let t = match (t0.is_finite(), t1 > t0) {
            (true, true) => (t0, t1),
            (true, false) => (t0 - 0.5, t0 + 0.5),
            _ => (0.0, 1.0),
        };
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
        let mut layers = SeriesLayers {
            t,
            points,
            averages,
            bands,
            outliers,
            target: finite_positive(target).map(y),
            corner: SeriesLabelPosition::UpperRight,
        };
        let at = |(tv, v): (f64, f64)| {
            let yv = if scale.log { v.ln() } else { v };
            ((tv - t.0) / (t.1 - t.0), (yv - ylo) / (yhi - ylo))
        };
        layers.corner = layers.emptiest_corner(at);
        layers
    }

    /// The corner whose legend-sized box covers the least: the points and the target line
    /// count once, the average and band edges three times, outliers most.
    fn emptiest_corner(&self, at: impl Fn((f64, f64)) -> (f64, f64)) -> SeriesLabelPosition {
        let mut weighted: Vec<((f64, f64), f64)> = Vec::new();
        weighted.extend(self.points.iter().map(|&p| (at(p), 1.0)));
        for line in self.averages.iter().chain(&self.bands) {
            weighted.extend(line.iter().map(|&p| (at(p), 3.0)));
        }
        weighted.extend(self.outliers.iter().map(|&p| (at(p), 5.0)));
        if let Some(target) = self.target {
            weighted.extend((0..=40).map(|i| {
                let tv = self.t.0 + (self.t.1 - self.t.0) * f64::from(i) / 40.0;
                (at((tv, target)), 1.0)
            }));
        }
        let corners = [
            (SeriesLabelPosition::UpperRight, true, true),
            (SeriesLabelPosition::UpperLeft, false, true),
            (SeriesLabelPosition::LowerRight, true, false),
            (SeriesLabelPosition::LowerLeft, false, false),
        ];
        let cover = |right: bool, upper: bool| {
            weighted
                .iter()
                .filter(|((x, y), _)| {
                    (if right {
                        *x > 1.0 - LEGEND.0
                    } else {
                        *x < LEGEND.0
                    }) && (if upper {
                        *y > 1.0 - LEGEND.1
                    } else {
                        *y < LEGEND.1
                    })
                })
                .map(|p| p.1)
                .sum::<f64>()
        };
        corners
            .into_iter()
            .map(|(c, right, upper)| (c, cover(right, upper)))
            .fold(
                None,
                |best: Option<(SeriesLabelPosition, f64)>, (c, w)| match best {
                    Some((_, bw)) if bw <= w => best,
                    _ => Some((c, w)),
                },
            )
            .map_or(SeriesLabelPosition::UpperRight, |b| b.0)
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

/// A sensor's NIS over time: each update as a small grey point, the moving-window average
/// (black line) in its interval (grey band), the target (dashed) and the outliers
/// (triangles), on the axis `scale` gives.
pub(super) fn nis_series_svg(
    title: &str,
    plot: &SensorPlot,
    target: f64,
    scale: &SeriesScale,
) -> String {
    let layers = SeriesLayers::new(plot, target, scale);
    render_sized(title, NIS_SIZE, |root| {
        draw_nis_series(root, title, &layers, scale)
    })
}

fn draw_nis_series(
    root: &DrawingArea<SVGBackend<'_>, Shift>,
    title: &str,
    layers: &SeriesLayers,
    scale: &SeriesScale,
) -> Drawn {
    let (t0, t1) = layers.t;
    let decimals = if t1 - t0 >= 10.0 { 0 } else { 1 };
    let x_fmt = move |x: &f64| format!("{x:.decimals$}");
    let mut builder = chart_builder(root, title, 55);
    if scale.log {
        let mut chart = builder.build_cartesian_2d(t0..t1, (scale.floor..scale.top).log_scale())?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("time (s)")
            .x_label_formatter(&x_fmt)
            .y_desc("NIS (log scale)")
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .axis_desc_style((FONT, 13))
            .draw()?;
        draw_nis_layers(&mut chart, layers)
    } else {
        let mut chart = builder.build_cartesian_2d(t0..t1, 0.0..scale.top)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("time (s)")
            .x_label_formatter(&x_fmt)
            .y_desc("NIS")
            .axis_desc_style((FONT, 13))
            .draw()?;
        draw_nis_layers(&mut chart, layers)
    }
}

fn draw_nis_layers<'a, Y: Ranged<ValueType = f64>>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<RangedCoordf64, Y>>,
    layers: &SeriesLayers,
) -> Drawn {
    if !layers.bands.is_empty() {
        chart
            .draw_series(
                layers
                    .bands
                    .iter()
                    .map(|b| Polygon::new(b.clone(), BAND.filled())),
            )?
            .label("window interval")
            .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 16, y + 5)], BAND.filled()));
    }
    chart
        .draw_series(
            layers
                .points
                .iter()
                .map(|&p| Circle::new(p, 1, POINT.filled())),
        )?
        .label("NIS of an update")
        .legend(|(x, y)| Circle::new((x + 8, y), 2, POINT.filled()));
    if !layers.averages.is_empty() {
        chart
            .draw_series(
                layers
                    .averages
                    .iter()
                    .map(|a| PathElement::new(a.clone(), BLACK.stroke_width(2))),
            )?
            .label("window average")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(2)));
    }
    if let Some(target) = layers.target {
        chart
            .draw_series(DashedLineSeries::new(
                vec![(layers.t.0, target), (layers.t.1, target)],
                6,
                4,
                MID.stroke_width(2),
            ))?
            .label("expected")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], MID.stroke_width(2)));
    }
    if !layers.outliers.is_empty() {
        chart
            .draw_series(
                layers
                    .outliers
                    .iter()
                    .map(|&p| TriangleMarker::new(p, 5, BLACK.filled())),
            )?
            .label("outlier")
            .legend(|(x, y)| TriangleMarker::new((x + 8, y), 5, BLACK.filled()));
    }
    legend_sized(chart, layers.corner.clone(), 11)
}

/// Samples of the χ² density drawn across the histogram.
const CURVE_POINTS: usize = 300;

/// The histogram of a sensor's NIS as a density (bars) against the `χ²(m)` density (line).
pub(super) fn nis_histogram_svg(title: &str, h: &Histogram) -> String {
    render_sized(title, NIS_SIZE, |root| draw_histogram(root, title, h))
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
    let ymax = density.iter().copied().fold(curve_top, f64::max).max(1e-9) * 1.15;
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
    chart
        .draw_series(
            density
                .iter()
                .enumerate()
                .map(|(i, &d)| Rectangle::new(bar(i, d), BAND.filled())),
        )?
        .label(format!("updates ({total:.0})"))
        .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 16, y + 5)], BAND.filled()));
    chart.draw_series(
        density
            .iter()
            .enumerate()
            .filter(|(_, d)| **d > 0.0)
            .map(|(i, &d)| Rectangle::new(bar(i, d), MID.stroke_width(1))),
    )?;
    chart
        .draw_series(LineSeries::new(
            curve.into_iter().skip_while(|p| p.1 > ymax),
            BLACK.stroke_width(2),
        ))?
        .label(format!("χ²({}) density", h.dof))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(2)));
    legend_sized(&mut chart, SeriesLabelPosition::UpperRight, 11)
}
