//! The time axis every time plot of `autotune nis` shares: its label (the log's own time
//! origin for a PX4 log) and the events marked on it as vertical lines — takeoff and
//! landing, aiding sources starting or stopping, primary-instance switches.

use plotters::coord::ranged1d::Ranged;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use super::legend::{LegendItem, Swatch};
use crate::fieldlog::{EventKind, Px4Event};
use crate::report::svg::Drawn;

/// Takeoff and landing: the darkest lines, solid and dashed.
pub(in crate::report) const FLIGHT: RGBColor = RGBColor(40, 40, 40);
/// Aiding-source changes: light and dotted, as there may be many.
pub(in crate::report) const AIDING: RGBColor = RGBColor(150, 150, 150);
/// Primary switches: mid grey, long dashes.
pub(in crate::report) const PRIMARY: RGBColor = RGBColor(90, 90, 90);

/// How a kind of event is drawn: colour, dash, gap (0: solid), width.
fn style(kind: EventKind) -> (RGBColor, u32, u32, u32) {
    match kind {
        EventKind::Takeoff => (FLIGHT, 1, 0, 2),
        EventKind::Landing => (FLIGHT, 6, 3, 2),
        EventKind::Aiding => (AIDING, 2, 3, 1),
        EventKind::Primary => (PRIMARY, 10, 4, 2),
    }
}

fn kind_label(kind: EventKind) -> &'static str {
    match kind {
        EventKind::Takeoff => "takeoff",
        EventKind::Landing => "landing",
        EventKind::Aiding => "aiding source change",
        EventKind::Primary => "primary switch",
    }
}

/// The x axis of a report's time plots.
#[derive(Debug, Clone, Default)]
pub(in crate::report) struct TimeAxis {
    /// The axis' description.
    pub label: String,
    /// Events to mark, seconds on the axis' scale.
    pub events: Vec<Px4Event>,
}

impl TimeAxis {
    /// A plain axis of seconds, without events.
    pub(in crate::report) fn plain() -> Self {
        TimeAxis {
            label: "time (s)".into(),
            events: Vec::new(),
        }
    }

    /// The axis of a PX4 log: seconds since the log's start, with its events.
    pub(in crate::report) fn px4(events: Vec<Px4Event>) -> Self {
        TimeAxis {
            label: "s since log start".into(),
            events,
        }
    }

    /// The events that concern the channel `sensor`: takeoff, landing and primary switches
    /// concern all; an aiding change named after an instance (`ekf1: GPS on`) only that
    /// instance's channels (`ekf1.…`).
    pub(in crate::report) fn for_sensor(&self, sensor: &str) -> TimeAxis {
        let events = self
            .events
            .iter()
            .filter(|e| e.time.is_finite())
            .filter(|e| match e.what.split_once(':') {
                Some((inst, _)) if e.kind == EventKind::Aiding && inst.starts_with("ekf") => {
                    sensor.starts_with(&format!("{inst}."))
                }
                _ => true,
            })
            .cloned()
            .collect();
        TimeAxis {
            label: self.label.clone(),
            events,
        }
    }

    /// `(t0, t1)` widened to the events, so that a takeoff before a channel's first update
    /// is still on its plot.
    pub(in crate::report) fn span(&self, (t0, t1): (f64, f64)) -> (f64, f64) {
        let (a, b) = self
            .events
            .iter()
            .map(|e| e.time)
            .fold((t0, t1), |(a, b), t| (a.min(t), b.max(t)));
        if b > a { (a, b) } else { (a - 0.5, a + 0.5) }
    }

    /// One legend entry per kind of event present, in a fixed order.
    pub(in crate::report) fn legend(&self) -> Vec<LegendItem> {
        [
            EventKind::Takeoff,
            EventKind::Landing,
            EventKind::Aiding,
            EventKind::Primary,
        ]
        .into_iter()
        .filter(|k| self.events.iter().any(|e| e.kind == *k))
        .map(|k| {
            let (c, dash, gap, w) = style(k);
            LegendItem::new(kind_label(k), Swatch::Vertical(c, dash, gap, w))
        })
        .collect()
    }
}

/// Draws each event as a vertical line from `y.0` to `y.1` (the y axis' ends, in its values).
pub(in crate::report) fn draw_events<'a, Y: Ranged<ValueType = f64>>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<RangedCoordf64, Y>>,
    axis: &TimeAxis,
    y: (f64, f64),
) -> Drawn {
    let (lo, hi) = {
        let r = chart.x_range();
        (r.start, r.end)
    };
    for e in axis.events.iter().filter(|e| e.time >= lo && e.time <= hi) {
        let (c, dash, gap, w) = style(e.kind);
        let line = vec![(e.time, y.0), (e.time, y.1)];
        if gap == 0 {
            chart.draw_series(std::iter::once(PathElement::new(line, c.stroke_width(w))))?;
        } else {
            chart.draw_series(DashedLineSeries::new(line, dash, gap, c.stroke_width(w)))?;
        }
    }
    Ok(())
}
