//! SVG plots (plotters' SVG backend: no system libraries, no fonts to load).
//!
//! Every plot is drawn in black and greys, told apart by fill, dash and marker shape, so it
//! stays legible printed in grey. A plot that cannot be drawn becomes a small SVG saying so;
//! a report is never lost for a plot.

use plotters::coord::Shift;
use plotters::coord::ranged1d::Ranged;
use plotters::element::{Drawable, PointCollection};
use plotters::prelude::*;

use crate::stats::WhitenessStat;

pub(crate) const BAND: RGBColor = RGBColor(210, 210, 210);

pub(crate) const MID: RGBColor = RGBColor(110, 110, 110);

const SIZE: (u32, u32) = (640, 380);

pub(crate) const FONT: &str = "sans-serif";

/// A drawing result: plotters' errors are boxed, whatever the backend.
pub(crate) type Drawn = Result<(), Box<dyn std::error::Error>>;

/// Draw a plot into an SVG string with `draw`; a plot that cannot be drawn becomes the
/// fallback naming it.
pub(crate) fn render(
    title: &str,
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> Drawn,
) -> String {
    render_sized(title, SIZE, draw)
}

/// [`render`] at `size` pixels.
pub(crate) fn render_sized(
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
pub(crate) fn chart_builder<'a, 'b>(
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
pub(crate) fn legend<'a, X: Ranged, Y: Ranged>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<X, Y>>,
    position: SeriesLabelPosition,
) -> Drawn {
    legend_sized(chart, position, 13)
}

/// [`legend`] in a `font`-pixel font.
pub(crate) fn legend_sized<'a, X: Ranged, Y: Ranged>(
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

pub(crate) fn fallback(title: &str, err: impl std::fmt::Display) -> String {
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"640\" height=\"60\"><text x=\"10\" y=\"30\">{}: plot unavailable ({})</text></svg>",
        crate::report::html::escape(title),
        crate::report::html::escape(&err.to_string())
    )
}

/// Innovation autocorrelation against lag, per measurement component, with the ±band in
/// which a white sequence's sample autocorrelation falls with probability 1 − α.
pub fn whiteness_svg(title: &str, white: &[WhitenessStat]) -> String {
    whiteness_svg_sized(title, white, SIZE)
}

/// [`whiteness_svg`] at `size` pixels.
pub(crate) fn whiteness_svg_sized(
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
