//! The summaries of a sensor's report: its gated NIS average and interval, the window and
//! histogram series, the component statistics and the outlier tail.

use std::collections::HashMap;

use serde::Serialize;
use statrs::function::beta::beta_reg;

use super::whiteness::*;
use crate::fieldlog::analysis::{HIST_BINS, SensorSums, SeriesPoint};
use crate::stats::{
    ComponentStat, Interval, Verdict, chi2_average_interval, has_power, scaled_chi2_interval,
};

/// A gated NIS average and its test.
#[derive(Debug, Clone, Serialize)]
pub struct NisAverage {
    /// Average NIS over the updates inside the outlier gate.
    pub mean: f64,
    /// What a consistent filter's gated average is (its dimension, less the tail the gate
    /// cuts off).
    pub target: f64,
    /// Single-run interval at the test level: the sum of K truncated `χ²(m)` variables,
    /// moment-matched (exactly `χ²(K m)/K` without the gate).
    pub interval: Interval,
    /// Degrees of freedom summed over the gated updates.
    pub dof: f64,
    /// Where the average falls ([`Verdict::Inconclusive`] when inside but the test could
    /// not tell a factor-2 error).
    pub verdict: Verdict,
}

/// The moving-window average over a sensor's log.
#[derive(Debug, Clone, Serialize)]
pub struct WindowSummary {
    /// Windows evaluated (one per gated update once the window has filled).
    pub windows: usize,
    /// Of those, outside their interval at α (each window's own `χ²` interval); about α of
    /// them for a consistent filter, in runs, since windows overlap.
    pub outside: usize,
    /// The lowest window average and its time (s).
    pub min: Option<(f64, f64)>,
    /// The highest window average and its time (s).
    pub max: Option<(f64, f64)>,
    /// The latest window's average and interval.
    pub last: Option<(f64, f64, f64)>,
}

/// A histogram of one dimension's NIS values, for the plot against the χ² density.
#[derive(Debug, Clone, Serialize)]
pub struct Histogram {
    /// The measurement dimension m.
    pub dof: usize,
    /// Upper end of the bins, `χ²⁻¹(0.999, m)`; bins are equal over `[0, top]`.
    pub top: f64,
    /// Counts per bin.
    pub counts: Vec<u64>,
    /// Values above `top`.
    pub above: u64,
}

/// What a sensor's report needs for its plots (not in the JSON).
#[derive(Debug, Clone, Default)]
pub struct SensorPlot {
    /// NIS and the window average over time, decimated to a few thousand points.
    pub series: Vec<SeriesPoint>,
    /// Outliers (time s, NIS), the first thousand.
    pub outliers: Vec<(f64, f64)>,
    /// The histogram of the most common dimension.
    pub histogram: Option<Histogram>,
}

/// `n_eff` in words: a whole number below 10, else two significant digits.
pub(super) fn about(n: f64) -> String {
    if n < 10.0 {
        format!("{:.0}", n.max(1.0))
    } else {
        let mag = 10f64.powi(n.log10().floor() as i32 - 1);
        format!("{:.0}", (n / mag).round() * mag)
    }
}

/// The interval of `sum / count` for a sum of gated χ² variables with the given mean and
/// variance.
pub(super) fn gated_interval(level: f64, mean: f64, var: f64, count: f64) -> Interval {
    if var > 0.0 {
        scaled_chi2_interval(level, mean, var, count).0
    } else {
        Interval {
            lower: mean / count,
            upper: mean / count,
        }
    }
}

/// What a sensor's time stamps put in doubt, in one line: all one time (zero or not), or
/// updates that do not come after the one before.
pub(super) fn time_warning(s: &SensorSums) -> Option<String> {
    let n = s.updates;
    if n < 2 {
        return None;
    }
    let name = &s.info.name;
    if s.time_min == s.time_max {
        let t = s.time_min;
        return Some(format!(
            "{name}: all {n} updates have time {}: the time axis and time windows are meaningless",
            if t == 0.0 { "0".to_string() } else { short(t) }
        ));
    }
    (s.non_increasing > 0).then(|| {
        format!(
            "{name}: {} of {n} updates do not come after the one before (equal or earlier time): the time axis and time windows are unreliable",
            s.non_increasing
        )
    })
}

/// `P(X ≥ k)` for `X ~ Binomial(n, p)`.
pub(super) fn binomial_tail(k: usize, n: usize, p: f64) -> f64 {
    if k == 0 {
        1.0
    } else if k > n {
        0.0
    } else {
        beta_reg(k as f64, (n - k + 1) as f64, p)
    }
}

/// The gated NIS average against its interval at `level` (widened by the correlation
/// `factor`), and why it is inconclusive when too few independent samples remain.
pub(super) fn nis_average(
    s: &SensorSums,
    level: f64,
    factor: f64,
    centred: &[CentredWhiteness],
) -> (NisAverage, Option<String>) {
    if s.gated == 0 {
        let nan = NisAverage {
            mean: f64::NAN,
            target: f64::NAN,
            interval: Interval {
                lower: f64::NAN,
                upper: f64::NAN,
            },
            dof: 0.0,
            verdict: Verdict::Inconclusive,
        };
        return (nan, None);
    }
    let mut inconclusive_reason = None;
    let count = s.gated as f64;
    let interval = gated_interval(level, s.mean_sum, s.var_sum * factor, count);
    let mean = s.nis_sum / count;
    let mut verdict = interval.classify(mean);
    let powered = has_power(level, s.dof_sum / factor);
    if factor > 1.0 && !powered {
        let worst = centred
            .iter()
            .max_by(|a, b| a.square_factor.total_cmp(&b.square_factor));
        inconclusive_reason = Some(format!(
            "not enough independent samples to judge: about {} of {}{}",
            about(s.gated as f64 / factor),
            s.gated,
            worst.map_or(String::new(), |w| format!(" (ρ₁ = {:+.2})", w.rho1))
        ));
        verdict = Verdict::Inconclusive;
    } else if verdict == Verdict::Consistent && !powered {
        verdict = Verdict::Inconclusive;
    }
    let average = NisAverage {
        mean,
        target: s.mean_sum / count,
        interval,
        dof: s.dof_sum,
        verdict,
    };
    (average, inconclusive_reason)
}

/// Each measured component's average of `u²` against its interval at `level` (widened by
/// its correlation factor), with its mean test. `intervals` caches the intervals by sample
/// count: a chi-square quantile costs microseconds, and a log may have thousands of
/// components.
pub(super) fn component_stats(
    s: &SensorSums,
    lags: usize,
    level: f64,
    centred: &[CentredWhiteness],
    intervals: &mut HashMap<u64, Interval>,
) -> Vec<ComponentStat> {
    (0..s.info.components.len())
        .filter(|&j| s.comp_n[j] > 0.0)
        .map(|j| {
            let n = s.comp_n[j];
            let f = centred
                .iter()
                .find(|c| c.component == s.info.components[j])
                .map_or(1.0, |c| c.square_factor);
            // The average of n u² with variance factor f is χ²(n/f)/(n/f).
            let interval = if f > 1.0 {
                chi2_average_interval(level, n / f, n / f)
            } else {
                *intervals
                    .entry(n.to_bits())
                    .or_insert_with(|| chi2_average_interval(level, n, n))
            };
            let value = s.comp_sum[j] / n;
            let verdict = if f > 1.0 && !has_power(level, n / f) {
                Verdict::Inconclusive
            } else {
                interval.classify(value)
            };
            let mt = mean_test(s, j, lags, level);
            ComponentStat {
                mean: s.comp_mean_sum[j] / n,
                mean_z: mt.as_ref().map_or(f64::NAN, |t| t.z),
                mean_verdict: mt.as_ref().map_or(Verdict::Inconclusive, |t| t.verdict),
                name: s.info.components[j].clone(),
                kind: "measurement",
                value,
                interval,
                samples: n,
                verdict,
            }
        })
        .collect()
}

/// The histogram of the NIS of the degrees of freedom with the most updates.
pub(super) fn histogram(s: &SensorSums) -> Option<Histogram> {
    let histogram = s
        .hist
        .iter()
        .max_by_key(|h| h.1.iter().sum::<u64>() + h.2)
        .map(|(dof, counts, above)| Histogram {
            dof: *dof,
            top: crate::stats::chi2_inv(0.999, *dof as f64),
            counts: counts.clone(),
            above: *above,
        });
    debug_assert!(
        histogram
            .as_ref()
            .is_none_or(|h| h.counts.len() == HIST_BINS)
    );
    histogram
}

/// A number in 4 significant digits, for the evidence text.
pub(in crate::fieldlog) fn short(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    if (1e-3..1e5).contains(&a) {
        let digits = (3 - a.log10().floor() as i32).clamp(0, 6) as usize;
        format!("{v:.digits$}")
    } else {
        format!("{v:.3e}")
    }
}
