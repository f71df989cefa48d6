//! The NIS axis of a sensor's time plot: linear unless the values span decades, and what
//! it clamps.

use crate::fieldlog::SensorPlot;

/// Decades the values may span before the NIS axis turns logarithmic. A consistent χ²(1)
/// channel spans about 1.6 (median 0.45 to the outlier gate's 19.5 at 1e-5), so two keep
/// it linear while a channel whose NIS collapses or explodes by 100× gets a log axis.
const LOG_DECADES: f64 = 2.0;
/// How far below the bulk (the median NIS, the lowest window average, the target) a
/// logarithmic axis reaches; lower values are drawn at its floor.
const LOG_REACH: f64 = 1e-3;
/// Room left above the data, as a share of the axis (the legend is under the plot).
const HEADROOM: f64 = 0.08;
/// How far above the largest gated value a linear axis reaches for outliers; higher ones
/// are drawn at the top edge.
const OUTLIER_REACH: f64 = 1.5;

/// How a sensor's NIS-over-time plot shows its values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(in crate::report) struct SeriesScale {
    /// A logarithmic y axis (the gated values span more than two decades).
    pub log: bool,
    /// Bottom of the axis: 0, or on a logarithmic axis the floor lower values are drawn at.
    pub floor: f64,
    /// Highest value drawn where it is; higher ones (outliers on a linear axis) are drawn
    /// at the top edge.
    pub ceiling: f64,
    /// Top of the axis.
    pub top: f64,
    /// Values (updates and outliers) below the floor, drawn at it.
    pub below: usize,
    /// Outliers above the ceiling, drawn at the top edge.
    pub above: usize,
    /// Decades between the bulk (the median NIS, the lowest window average, the target) and
    /// the largest gated value.
    pub decades: f64,
}

impl SeriesScale {
    /// Where the value `v` is drawn.
    pub(super) fn display(&self, v: f64) -> f64 {
        if v > self.ceiling {
            self.top
        } else {
            v.max(self.floor)
        }
    }
}

pub(super) fn finite_positive(v: f64) -> Option<f64> {
    (v.is_finite() && v > 0.0).then_some(v)
}

/// The y axis for a sensor's values and its `target` (NaN when unknown): linear unless the
/// gated values span more than two decades. A linear axis keeps the gated values in view
/// and draws far outliers at its top edge; a logarithmic one shows them all and draws
/// values far below the bulk at its floor.
pub(in crate::report) fn series_scale(plot: &SensorPlot, target: f64) -> SeriesScale {
    let mut positive: Vec<f64> = plot
        .series
        .iter()
        .filter_map(|p| finite_positive(p.nis))
        .collect();
    positive.sort_by(f64::total_cmp);
    let median = positive.get(positive.len() / 2).copied();
    let windows = plot.series.iter().filter_map(|p| p.window);
    let lo = median
        .into_iter()
        .chain(windows.filter_map(finite_positive))
        .chain(finite_positive(target))
        .fold(f64::INFINITY, f64::min);
    let gated_hi = plot
        .series
        .iter()
        .flat_map(|p| [Some(p.nis), p.window, p.upper])
        .flatten()
        .chain(Some(target))
        .filter(|v| v.is_finite())
        .fold(0.0_f64, f64::max);
    let gated_hi = if gated_hi > 0.0 { gated_hi } else { 1.0 };
    let outliers: Vec<f64> = plot
        .outliers
        .iter()
        .map(|o| o.1)
        .filter(|v| v.is_finite())
        .collect();
    let outlier_hi = outliers.iter().copied().fold(0.0_f64, f64::max);
    let decades = if lo.is_finite() {
        (gated_hi / lo).log10()
    } else {
        0.0
    };
    if decades <= LOG_DECADES {
        let ceiling = if outlier_hi > gated_hi * OUTLIER_REACH {
            gated_hi * OUTLIER_REACH
        } else {
            gated_hi.max(outlier_hi)
        };
        return SeriesScale {
            log: false,
            floor: 0.0,
            ceiling,
            top: ceiling / (1.0 - HEADROOM),
            below: 0,
            above: outliers.iter().filter(|v| **v > ceiling).count(),
            decades,
        };
    }
    let hi = gated_hi.max(outlier_hi);
    let lowest = plot
        .series
        .iter()
        .map(|p| p.nis)
        .chain(outliers.iter().copied())
        .filter_map(finite_positive)
        .fold(f64::INFINITY, f64::min);
    let floor = (lo * LOG_REACH).max(lowest * 0.7);
    let top = hi * (hi / floor).powf(HEADROOM / (1.0 - HEADROOM));
    SeriesScale {
        log: true,
        floor,
        ceiling: top,
        top,
        below: plot
            .series
            .iter()
            .map(|p| p.nis)
            .chain(outliers.iter().copied())
            .filter(|v| v.is_finite() && *v < floor)
            .count(),
        above: 0,
        decades,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fieldlog::SeriesPoint;

    fn point(t: f64, nis: f64) -> SeriesPoint {
        SeriesPoint {
            innovation: None,
            t,
            nis,
            window: Some(nis),
            lower: Some(0.5),
            upper: Some(1.5),
        }
    }

    #[test]
    fn the_axis_turns_logarithmic_only_when_the_values_span_decades() {
        let plot = |v: f64| SensorPlot {
            series: (0..100).map(|i| point(i as f64, v)).collect(),
            ..SensorPlot::default()
        };
        let s = series_scale(&plot(0.8), 1.0);
        assert!(!s.log && s.floor == 0.0 && s.top > 1.5);
        let s = series_scale(&plot(1e-6), 1.0);
        assert!(s.log && s.floor > 0.0 && s.floor <= 1e-6 && s.below == 0);
        let mut p = plot(1e-6);
        p.series[3].nis = 0.0;
        p.outliers.push((3.0, 1e4));
        let s = series_scale(&p, 1.0);
        assert!(s.below == 1 && s.above == 0 && s.top > 1e4);
        // A far outlier over white NIS: linear, the outlier at the top edge.
        let mut p = plot(0.8);
        p.outliers.push((3.0, 1e4));
        let s = series_scale(&p, 1.0);
        assert!(!s.log && s.above == 1 && s.top < 10.0 && s.display(1e4) == s.top);
        // Issue 23: 2.5 decades between the bulk and the top already call for a log axis;
        // a consistent χ²(1) channel's 1.6 (median 0.45, largest 18) does not.
        let spread = |hi: f64, median: f64| SensorPlot {
            series: (0..101)
                .map(|i| SeriesPoint {
                    window: None,
                    lower: None,
                    upper: None,
                    ..point(i as f64, if i % 50 == 0 { hi } else { median })
                })
                .collect(),
            ..SensorPlot::default()
        };
        let s = series_scale(&spread(18.0, 0.45), 1.0);
        assert!(!s.log && (s.decades - (18.0_f64 / 0.45).log10()).abs() < 1e-9);
        let s = series_scale(&spread(1.0, 10f64.powf(-2.5)), 1.0);
        assert!(s.log && (s.decades - 2.5).abs() < 1e-9);
        let empty = series_scale(&SensorPlot::default(), f64::NAN);
        assert!(!empty.log && empty.top > 0.0);
    }
}
