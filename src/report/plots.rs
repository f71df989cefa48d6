//! SVG plots (plotters' SVG backend: no system libraries, no fonts to load).
//!
//! Every plot is drawn in black and greys, told apart by fill, dash and marker shape, so it
//! stays legible printed in grey. A plot that cannot be drawn becomes a small SVG saying so;
//! a report is never lost for a plot.

use plotters::coord::Shift;
use plotters::coord::ranged1d::Ranged;
use plotters::element::{Drawable, PointCollection};
use plotters::prelude::*;

use crate::stats::{ComponentStat, StatisticSummary, WhitenessStat};

pub(super) const BAND: RGBColor = RGBColor(210, 210, 210);
pub(super) const MID: RGBColor = RGBColor(110, 110, 110);
const SIZE: (u32, u32) = (640, 380);
pub(super) const FONT: &str = "sans-serif";

/// A drawing result: plotters' errors are boxed, whatever the backend.
pub(super) type Drawn = Result<(), Box<dyn std::error::Error>>;

/// Draw a plot into an SVG string with `draw`; a plot that cannot be drawn becomes the
/// fallback naming it.
fn render(title: &str, draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> Drawn) -> String {
    render_sized(title, SIZE, draw)
}

/// [`render`] at `size` pixels.
pub(super) fn render_sized(
    title: &str,
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> Drawn,
) -> String {
    let mut buf = String::new();
    let result = {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE)
            .map_err(Into::into)
            .and_then(|()| draw(&root))
            .and_then(|()| root.present().map_err(Into::into))
    };
    match result {
        Ok(()) => buf,
        Err(e) => fallback(title, e),
    }
}

/// The chart every plot starts from: the title, margins and label areas (`y_area` wide).
pub(super) fn chart_builder<'a, 'b>(
    root: &'a DrawingArea<SVGBackend<'b>, Shift>,
    title: &str,
    y_area: u32,
) -> ChartBuilder<'a, 'b, SVGBackend<'b>> {
    let mut b = ChartBuilder::on(root);
    b.caption(title, (FONT, 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(y_area);
    b
}

/// The series legend, boxed on a translucent white ground at `position`.
fn legend<'a, X: Ranged, Y: Ranged>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<X, Y>>,
    position: SeriesLabelPosition,
) -> Drawn {
    legend_sized(chart, position, 13)
}

/// [`legend`] in a `font`-pixel font.
pub(super) fn legend_sized<'a, X: Ranged, Y: Ranged>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<X, Y>>,
    position: SeriesLabelPosition,
    font: u32,
) -> Drawn {
    chart
        .configure_series_labels()
        .label_font((FONT, font))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(position)
        .draw()?;
    Ok(())
}

fn fallback(title: &str, err: impl std::fmt::Display) -> String {
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"640\" height=\"60\"><text x=\"10\" y=\"30\">{}: plot unavailable ({})</text></svg>",
        super::html::escape(title),
        super::html::escape(&err.to_string())
    )
}

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

/// Innovation autocorrelation against lag, per measurement component, with the ±band in
/// which a white sequence's sample autocorrelation falls with probability 1 − α.
pub fn whiteness_svg(title: &str, white: &[WhitenessStat]) -> String {
    whiteness_svg_sized(title, white, SIZE)
}

/// [`whiteness_svg`] at `size` pixels.
pub(super) fn whiteness_svg_sized(
    title: &str,
    white: &[WhitenessStat],
    size: (u32, u32),
) -> String {
    let compact = size.1 < SIZE.1;
    render_sized(title, size, |root| {
        draw_whiteness(root, title, white, compact)
    })
}

/// The side (upper or lower right) where the legend, over the right 60% of the lags,
/// covers less of a whiteness plot.
fn whiteness_corner(white: &[WhitenessStat], lags: usize) -> SeriesLabelPosition {
    let right = white.iter().filter(|w| 5 * w.lag > 2 * lags);
    let up = right.clone().map(|w| w.rho.max(w.band)).fold(0.0, f64::max);
    let down = right.map(|w| (-w.rho).max(w.band)).fold(0.0, f64::max);
    if up <= down {
        SeriesLabelPosition::UpperRight
    } else {
        SeriesLabelPosition::LowerRight
    }
}

fn draw_whiteness(
    root: &DrawingArea<SVGBackend<'_>, Shift>,
    title: &str,
    white: &[WhitenessStat],
    compact: bool,
) -> Drawn {
    let lags = white.iter().map(|w| w.lag).max().unwrap_or(1);
    let amp = white
        .iter()
        .map(|w| w.rho.abs().max(w.band))
        .fold(0.05_f64, f64::max)
        * if compact { 1.6 } else { 1.2 };
    let mut comps: Vec<&str> = Vec::new();
    for w in white {
        if !comps.contains(&w.component.as_str()) {
            comps.push(&w.component);
        }
    }
    let mut chart =
        chart_builder(root, title, 60).build_cartesian_2d(0.5f64..lags as f64 + 0.5, -amp..amp)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(lags)
        .x_label_formatter(&|x| format!("{x:.0}"))
        .x_desc("lag (steps)")
        .y_desc("normalized autocorrelation ρ")
        .y_label_formatter(&|v| tick(*v, if amp > 0.5 { 1 } else { 2 }))
        .axis_desc_style((FONT, 14))
        .draw()?;
    // The band is the same for every component at a lag when all are measured together;
    // draw the widest.
    let band_at = |lag: usize| {
        white
            .iter()
            .filter(|w| w.lag == lag)
            .map(|w| w.band)
            .fold(0.0_f64, f64::max)
    };
    let mut poly: Vec<(f64, f64)> = (1..=lags).map(|l| (l as f64, band_at(l))).collect();
    poly.extend((1..=lags).rev().map(|l| (l as f64, -band_at(l))));
    if lags == 1 {
        poly = vec![
            (0.7, band_at(1)),
            (1.3, band_at(1)),
            (1.3, -band_at(1)),
            (0.7, -band_at(1)),
        ];
    }
    chart
        .draw_series(std::iter::once(Polygon::new(poly, BAND.filled())))?
        .label("band of a white sequence (1-α)")
        .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 16, y + 5)], BAND.filled()));
    for (ci, name) in comps.iter().enumerate() {
        let pts: Vec<(f64, f64)> = white
            .iter()
            .filter(|w| w.component == *name)
            .map(|w| (w.lag as f64, w.rho))
            .collect();
        let style = if ci % 2 == 0 {
            BLACK.stroke_width(1)
        } else {
            MID.stroke_width(1)
        };
        chart.draw_series(LineSeries::new(pts.clone(), style))?;
        let marker = ci % 3;
        chart
            .draw_series(pts.iter().map(move |&p| marker_at(marker, p)))?
            .label(format!("ρ of {name}"))
            .legend(move |(x, y)| marker_at(marker, (x + 8, y)));
    }
    chart.draw_series(LineSeries::new(
        vec![(0.5, 0.0), (lags as f64 + 0.5, 0.0)],
        MID.stroke_width(1),
    ))?;
    if compact {
        legend_sized(&mut chart, whiteness_corner(white, lags), 11)
    } else {
        legend(&mut chart, SeriesLabelPosition::UpperRight)
    }
}

/// A tick label with `decimals` decimals, without the sign of a value that rounds to 0.
fn tick(v: f64, decimals: usize) -> String {
    let t = format!("{v:.decimals$}");
    match t.strip_prefix('-') {
        Some(z) if z.chars().all(|c| c == '0' || c == '.') => z.to_string(),
        _ => t,
    }
}

/// Marker `kind` (0 a disc, 1 a triangle, else a cross) at `at`, in data or pixel
/// coordinates.
fn marker_at<'a, C: Clone + 'static>(kind: usize, at: C) -> DynElement<'static, SVGBackend<'a>, C>
where
    Circle<C, i32>: Drawable<SVGBackend<'a>>,
    TriangleMarker<C, i32>: Drawable<SVGBackend<'a>>,
    Cross<C, i32>: Drawable<SVGBackend<'a>>,
    for<'b> &'b Circle<C, i32>: PointCollection<'b, C>,
    for<'b> &'b TriangleMarker<C, i32>: PointCollection<'b, C>,
    for<'b> &'b Cross<C, i32>: PointCollection<'b, C>,
{
    match kind {
        0 => Circle::new(at, 4, BLACK.filled()).into_dyn(),
        1 => TriangleMarker::new(at, 5, BLACK.filled()).into_dyn(),
        _ => Cross::new(at, 4, BLACK.stroke_width(2)).into_dyn(),
    }
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
