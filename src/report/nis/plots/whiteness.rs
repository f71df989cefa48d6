//! A sensor's innovation autocorrelation for the `autotune nis` report: the same plot as
//! [`crate::report::svg::whiteness_svg_sized`], with its legend in the strip under it like
//! the report's other plots, since a component's ρ at the first lags sits where a legend
//! box in a corner would be.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::legend::{LegendItem, Swatch};
use super::render_with_legend;
use crate::report::svg::{BAND, Drawn, FONT, MID, chart_builder};
use crate::stats::WhitenessStat;

/// The marker of the `i`-th component: a disc, a triangle, a cross, in turn.
fn marker(i: usize) -> Swatch {
    match i % 3 {
        0 => Swatch::Disc(BLACK),
        1 => Swatch::Triangle(BLACK),
        _ => Swatch::Cross(BLACK),
    }
}

/// Component names in their first order of appearance.
fn components(white: &[WhitenessStat]) -> Vec<&str> {
    let mut comps: Vec<&str> = Vec::new();
    for w in white {
        if !comps.contains(&w.component.as_str()) {
            comps.push(&w.component);
        }
    }
    comps
}

/// Normalized autocorrelation of each component against lag, in the band a white
/// sequence's stays in with probability 1 − α, the legend under the plot.
pub(in crate::report) fn nis_whiteness_svg(title: &str, white: &[WhitenessStat]) -> String {
    let mut items = vec![LegendItem::new(
        "band of a white sequence (1-α)",
        Swatch::Fill(BAND),
    )];
    items.extend(
        components(white)
            .iter()
            .enumerate()
            .map(|(i, c)| LegendItem::new(format!("ρ of {c}"), marker(i))),
    );
    render_with_legend(title, &items, |root| draw(root, title, white))
}

fn draw(root: &DrawingArea<SVGBackend<'_>, Shift>, title: &str, white: &[WhitenessStat]) -> Drawn {
    let lags = white.iter().map(|w| w.lag).max().unwrap_or(1).max(1);
    let amp = white
        .iter()
        .map(|w| w.rho.abs().max(w.band))
        .filter(|v| v.is_finite())
        .fold(0.05_f64, f64::max)
        * 1.1;
    let mut chart =
        chart_builder(root, title, 60).build_cartesian_2d(0.5f64..lags as f64 + 0.5, -amp..amp)?;
    let decimals = if amp > 0.5 { 1 } else { 2 };
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(lags)
        .x_label_formatter(&|x| format!("{x:.0}"))
        .x_desc("lag (updates)")
        .y_desc("normalized autocorrelation ρ")
        .y_label_formatter(&|v| format!("{v:.decimals$}"))
        .axis_desc_style((FONT, 13))
        .draw()?;
    // Components measured together share the band at a lag; draw the widest.
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
        let b = band_at(1);
        poly = vec![(0.7, b), (1.3, b), (1.3, -b), (0.7, -b)];
    }
    chart.draw_series(std::iter::once(Polygon::new(poly, BAND.filled())))?;
    chart.draw_series(std::iter::once(PathElement::new(
        vec![(0.5, 0.0), (lags as f64 + 0.5, 0.0)],
        MID.stroke_width(1),
    )))?;
    for (ci, name) in components(white).iter().enumerate() {
        let pts: Vec<(f64, f64)> = white
            .iter()
            .filter(|w| w.component == *name && w.rho.is_finite())
            .map(|w| (w.lag as f64, w.rho))
            .collect();
        let line = if ci % 2 == 0 { BLACK } else { MID };
        chart.draw_series(std::iter::once(PathElement::new(
            pts.clone(),
            line.stroke_width(1),
        )))?;
        match ci % 3 {
            0 => chart.draw_series(pts.iter().map(|&p| Circle::new(p, 4, BLACK.filled())))?,
            1 => chart.draw_series(
                pts.iter()
                    .map(|&p| TriangleMarker::new(p, 5, BLACK.filled())),
            )?,
            _ => chart.draw_series(pts.iter().map(|&p| Cross::new(p, 4, BLACK.stroke_width(2))))?,
        };
    }
    Ok(())
}
