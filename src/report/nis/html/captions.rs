//! The words of the `autotune nis` report: numbers and counts for its tables, and the
//! captions that say what each plot shows and what a consistent filter looks like on it.

use std::fmt::Write;

use crate::fieldlog::EventKind;
use crate::fieldlog::{NisReport, SensorReport};
use crate::report::format::fmt_g;
use crate::report::nis::plots::{InnovationSummary, SeriesScale, TimeAxis};
use crate::stats::Verdict;

/// A count a consistent filter would have, in few digits.
pub(super) fn short(v: f64) -> String {
    if v >= 10.0 || v == 0.0 {
        format!("{v:.0}")
    } else if v >= 0.01 {
        format!("{v:.2}")
    } else {
        format!("{v:.1e}")
    }
}

/// `n` and the noun, in the plural unless one.
pub(super) fn count(n: u64, noun: &str) -> String {
    if n == 1 {
        format!("{n} {noun}")
    } else {
        format!("{n} {noun}s")
    }
}

/// A number for the tables: 4 significant digits, a dash when there is none.
pub(super) fn num(v: f64) -> String {
    if v.is_finite() {
        fmt_g(v)
    } else {
        "–".into()
    }
}

pub(super) fn interval(s: &SensorReport) -> String {
    let i = &s.nis.interval;
    if i.lower.is_finite() && i.upper.is_finite() {
        format!("[{}, {}]", fmt_g(i.lower), fmt_g(i.upper))
    } else {
        "–".into()
    }
}

/// What the vertical lines of a time plot mark, as a sentence (empty without events).
fn events_sentence(axis: &TimeAxis) -> String {
    let kinds = [
        (EventKind::Takeoff, "takeoff (solid)"),
        (EventKind::Landing, "landing (dashed)"),
        (
            EventKind::Aiding,
            "an aiding source starting or stopping (dotted)",
        ),
        (
            EventKind::Primary,
            "a switch of the primary instance (long dashes)",
        ),
    ];
    let present: Vec<&str> = kinds
        .iter()
        .filter(|(k, _)| axis.events.iter().any(|e| e.kind == *k))
        .map(|(_, w)| *w)
        .collect();
    if present.is_empty() {
        String::new()
    } else {
        format!(
            " Vertical lines mark {}; the PX4 section lists them.",
            present.join(", ")
        )
    }
}

/// The caption of the NIS-over-time plot.
pub(super) fn series_caption(
    r: &NisReport,
    s: &SensorReport,
    scale: &SeriesScale,
    axis: &TimeAxis,
) -> String {
    let mut c = format!(
        "NIS of each update (grey dots{}), its average over a moving window of {} (black line) in the window's {:.0}% interval (grey band), the expected value {} (dashed), outliers beyond the gate (triangles: {}, about {} expected). Consistent: the black line wanders around the dashed one inside the band, and triangles are rare.",
        if s.plot.series.len() < s.updates.saturating_sub(s.outliers) {
            format!(
                ", {} of {} shown",
                s.plot.series.len(),
                s.updates - s.outliers
            )
        } else {
            String::new()
        },
        r.window.describe(),
        100.0 * (1.0 - r.alpha),
        num(s.nis.target),
        s.outliers,
        short(s.outliers_expected)
    );
    if s.plot.outliers.len() < s.outliers {
        let _ = write!(
            c,
            " Only the first {} are drawn.",
            count(s.plot.outliers.len() as u64, "outlier")
        );
    }
    if scale.log {
        let _ = write!(
            c,
            " Logarithmic axis: the values span {:.1} decades.",
            scale.decades
        );
    }
    if scale.below > 0 {
        let _ = write!(
            c,
            " {} below {} drawn at the axis floor.",
            count(scale.below as u64, "value"),
            fmt_g(scale.floor)
        );
    }
    if scale.above > 0 {
        let _ = write!(
            c,
            " {} above {} drawn at the top edge.",
            count(scale.above as u64, "outlier"),
            fmt_g(scale.ceiling)
        );
    }
    if s.window.windows == 0 {
        c.push_str(" The window never filled: no average or band is drawn.");
    }
    c.push_str(&events_sentence(axis));
    c
}

/// The caption of the innovation plot.
pub(super) fn innovation_caption(
    s: &SensorReport,
    v: &InnovationSummary,
    unit: &str,
    axis: &TimeAxis,
) -> String {
    let share = |k: usize| {
        if v.points > 0 {
            format!("{:.0}%", 100.0 * k as f64 / v.points as f64)
        } else {
            "–".into()
        }
    };
    let mut c = format!(
        "Innovation ν of {} ({unit}, black dots, {} updates within the outlier gate) in its own ±√S band (grey) and ±2√S (light grey). Here {} of the points lie inside ±√S and {} inside ±2√S; a consistent filter has about 68% and 95%, centred on zero. A cloud off zero is a bias, points spilling out of the bands an S too small, points hugging zero an S too large.",
        s.components.first().map_or_else(
            || "the first component".to_string(),
            |n| format!("component {n}")
        ),
        v.points,
        share(v.inside_1),
        share(v.inside_2)
    );
    if v.clipped > 0 {
        let _ = write!(
            c,
            " {} beyond ±{} drawn at the edge.",
            count(v.clipped as u64, "value"),
            fmt_g(v.reach)
        );
    }
    if v.band_clipped > 0 {
        let _ = write!(
            c,
            " The band of {} (S large while the filter converges, or a gap) is wider than the axis and cut at its edge.",
            count(v.band_clipped as u64, "update")
        );
    }
    c.push_str(&events_sentence(axis));
    c
}

/// The caption of the histogram.
pub(super) fn histogram_caption(s: &SensorReport) -> String {
    let Some(h) = &s.plot.histogram else {
        return String::new();
    };
    let total = h.counts.iter().sum::<u64>() + h.above;
    format!(
        "Histogram of the NIS of {} of dimension m = {} (bars, as a density) against the χ²({}) density (line). Beyond the range's end {} (the χ² 99.9% point): {}, where a consistent filter would have about {}. A consistent filter's bars follow the curve; bars piled at 0 say S is too large, a long tail or many beyond the range that S is too small.",
        count(total, "update"),
        h.dof,
        h.dof,
        fmt_g(h.top),
        count(h.above, "update"),
        short(0.001 * total as f64)
    )
}

/// The caption of the autocorrelation plot.
pub(super) fn whiteness_caption(r: &NisReport, s: &SensorReport) -> String {
    let mut c = format!(
        "Normalized autocorrelation ρ of ν/√S over the sensor's own updates at lags 1..{}, one series per component, in the band a white sequence stays in with probability {:.0}% (grey). Consistent: the innovations are white and ρ stays in the band at every lag; a positive ρ₁ beyond it says the filter follows the measurements too slowly, a negative one too eagerly.",
        r.lags,
        100.0 * (1.0 - r.alpha)
    );
    for t in &s.whiteness_tests {
        let _ = write!(
            c,
            " {}: portmanteau Q = {} against {} ({}).",
            t.component,
            fmt_g(t.statistic),
            fmt_g(t.threshold),
            if t.verdict == Verdict::NotWhite {
                "not white"
            } else {
                "white"
            }
        );
    }
    c
}
