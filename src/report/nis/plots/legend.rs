//! Legends in a strip under a plot's axes, so that no legend box ever hides a curve: the
//! plot is drawn in the upper part of its SVG and the legend's entries, in rows, below it.

use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;

use crate::report::svg::{Drawn, FONT};

/// How an entry's sample is drawn (each kind as the plot draws its series).
#[derive(Debug, Clone, Copy)]
pub(in crate::report) enum Swatch {
    /// A filled box, for bands and bars.
    Fill(RGBColor),
    /// A dot, for per-update points.
    Dot(RGBColor),
    /// A horizontal line of this width.
    Line(RGBColor, u32),
    /// A horizontal dashed line (dash, gap, width).
    Dashed(RGBColor, u32, u32, u32),
    /// A filled triangle, for outliers and a series' markers.
    Triangle(RGBColor),
    /// A large disc, for a series' markers.
    Disc(RGBColor),
    /// A cross, for a series' markers.
    Cross(RGBColor),
    /// A short vertical line (dash, gap — equal dash and gap 0 for solid — and width), for
    /// the time markers.
    Vertical(RGBColor, u32, u32, u32),
}

/// One legend entry.
#[derive(Debug, Clone)]
pub(in crate::report) struct LegendItem {
    /// What the entry says.
    pub label: String,
    /// How its sample is drawn.
    pub swatch: Swatch,
}

impl LegendItem {
    pub(in crate::report) fn new(label: impl Into<String>, swatch: Swatch) -> Self {
        LegendItem {
            label: label.into(),
            swatch,
        }
    }
}

/// Font of the entries as plotters takes it (it writes about 0.8 of it as the SVG size).
const FONT_PX: u32 = 13;
/// Height of a row of entries, pixels.
const ROW: u32 = 15;
/// Width of an entry's sample and the gap after it, pixels.
const SAMPLE: i32 = 18;
const GAP: i32 = 5;
/// Space between entries on a row, pixels.
const SPACING: i32 = 14;
/// Left and right margin of the strip, pixels.
const MARGIN: i32 = 12;

/// A conservative width of `label` in the legend's font: an average sans-serif glyph at
/// the 10.5 px plotters writes is under 6 px wide, so entries never overlap whichever font
/// the browser picks.
fn text_width(label: &str) -> i32 {
    (label.chars().count() as f64 * 6.0).ceil() as i32
}

/// The top-left corner of each entry in a strip `width` pixels wide, and the number of rows.
fn layout(items: &[LegendItem], width: u32) -> (Vec<(i32, i32)>, u32) {
    let right = width as i32 - MARGIN;
    let mut at = Vec::with_capacity(items.len());
    let (mut x, mut row) = (MARGIN, 0_i32);
    for item in items {
        let w = SAMPLE + GAP + text_width(&item.label);
        if x > MARGIN && x + w > right {
            x = MARGIN;
            row += 1;
        }
        at.push((x, row * ROW as i32));
        x += w + SPACING;
    }
    let rows = if items.is_empty() { 0 } else { row as u32 + 1 };
    (at, rows)
}

/// Height of the strip the entries need under a plot `width` pixels wide (0 for none).
pub(in crate::report) fn strip_height(items: &[LegendItem], width: u32) -> u32 {
    match layout(items, width).1 {
        0 => 0,
        rows => rows * ROW + 6,
    }
}

/// Draws the entries into `area`, the strip under a plot.
pub(in crate::report) fn draw_legend(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    items: &[LegendItem],
) -> Drawn {
    let (at, _) = layout(items, area.dim_in_pixel().0);
    for (item, &(x, y)) in items.iter().zip(&at) {
        let mid = y + 2 + ROW as i32 / 2;
        draw_swatch(area, item.swatch, x, mid)?;
        area.draw(&Text::new(
            item.label.clone(),
            (x + SAMPLE + GAP, mid - FONT_PX as i32 / 2 - 1),
            (FONT, FONT_PX),
        ))?;
    }
    Ok(())
}

fn draw_swatch(area: &DrawingArea<SVGBackend<'_>, Shift>, s: Swatch, x: i32, y: i32) -> Drawn {
    match s {
        Swatch::Fill(c) => area.draw(&Rectangle::new([(x, y - 5), (x + 16, y + 5)], c.filled()))?,
        Swatch::Dot(c) => area.draw(&Circle::new((x + 8, y), 2, c.filled()))?,
        Swatch::Line(c, w) => area.draw(&PathElement::new(
            vec![(x, y), (x + 16, y)],
            c.stroke_width(w),
        ))?,
        Swatch::Dashed(c, dash, gap, w) => area.draw(&DashedPathElement::new(
            vec![(x, y), (x + 16, y)],
            dash,
            gap,
            c.stroke_width(w),
        ))?,
        Swatch::Triangle(c) => area.draw(&TriangleMarker::new((x + 8, y), 5, c.filled()))?,
        Swatch::Disc(c) => area.draw(&Circle::new((x + 8, y), 4, c.filled()))?,
        Swatch::Cross(c) => area.draw(&Cross::new((x + 8, y), 4, c.stroke_width(2)))?,
        Swatch::Vertical(c, dash, gap, w) => {
            let line = vec![(x + 8, y - 6), (x + 8, y + 6)];
            if gap == 0 {
                area.draw(&PathElement::new(line, c.stroke_width(w)))?;
            } else {
                area.draw(&DashedPathElement::new(line, dash, gap, c.stroke_width(w)))?;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_wrap_into_rows_that_fit_the_width() {
        let items: Vec<LegendItem> = (0..6)
            .map(|i| LegendItem::new(format!("entry number {i}"), Swatch::Dot(BLACK)))
            .collect();
        let (at, rows) = layout(&items, 440);
        assert!(rows >= 2, "six long entries need more than one row");
        for (item, &(x, _)) in items.iter().zip(&at) {
            assert!(x + SAMPLE + GAP + text_width(&item.label) <= 440 - MARGIN);
        }
        assert_eq!(strip_height(&[], 440), 0);
        assert_eq!(strip_height(&items, 440), rows * ROW + 6);
    }
}
