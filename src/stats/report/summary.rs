//! One statistic's summary ([`StatisticSummary`]): its per-step averages against their
//! intervals and its time average against the gate's, computed from the engine's sums. Apart
//! from the report so that the gate's combination reads without the per-statistic detail.

use serde::Serialize;

use crate::stats::interval::{
    Interval, SumVariance, Verdict, chi2_average_interval, gate_interval, has_power,
};

/// Per-step and time-averaged results for one statistic (NEES or NIS).
#[derive(Debug, Clone, Serialize)]
pub struct StatisticSummary {
    /// "NEES" or "NIS".
    pub name: String,
    /// Per-step average over runs (`ANEES_k` / `ANIS_k`), k = 1..T; `null` where no run
    /// contributed (no measurement at that step).
    pub per_step: Vec<Option<f64>>,
    /// Per-step lower bound `r1`.
    pub per_step_lower: Vec<Option<f64>>,
    /// Per-step upper bound `r2`.
    pub per_step_upper: Vec<Option<f64>>,
    /// Per-step degrees-of-freedom target (`n_x`, or the mean `n_z` of that step).
    pub per_step_target: Vec<Option<f64>>,
    /// Fraction of steps with data whose average lies inside `[r1, r2]`; about `1 − α`
    /// for a consistent filter.
    pub fraction_in_bounds: f64,
    /// Number of steps with data.
    pub steps_with_data: usize,
    /// Whether the per-step tests can detect a factor-2 covariance error (see `has_power`).
    pub per_step_has_power: bool,
    /// Time average over all runs and steps.
    pub time_average: f64,
    /// Its degrees-of-freedom target (mean dimension).
    pub target: f64,
    /// The textbook interval assuming steps are independent (`Σ N n` degrees of freedom), at
    /// the statistic's level.
    pub naive_interval: Interval,
    /// Total degrees of freedom of the naive interval.
    pub naive_dof: f64,
    /// The interval the verdict uses, accounting for correlation over time, at the
    /// statistic's level ([`super::ConsistencyReport::statistic_alpha`]).
    pub interval: Interval,
    /// Effective degrees of freedom of [`Self::interval`].
    pub effective_dof: f64,
    /// Set when the interval rests on the spread of this many per-run sums instead of the
    /// filter's prediction (a filter that supplies no error map; see
    /// [`crate::filter::Filter`]); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub run_spread_runs: Option<usize>,
    /// Set when the interval rests on batch means over the steps of one run (a single
    /// recording whose filter supplies no error map): the number of blocks of consecutive
    /// steps; absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub batch_spread_batches: Option<usize>,
    /// Whether the time-averaged test can detect a factor-2 covariance error.
    pub has_power: bool,
    /// Verdict of the time-averaged test.
    pub verdict: Verdict,
}

/// Chi-square quantiles cost microseconds each; a problem has only a handful of distinct
/// (dof, count) pairs, so compute each once.
pub(super) struct IntervalCache {
    alpha: f64,
    entries: Vec<((u64, u64), Interval)>,
}

impl IntervalCache {
    pub(super) fn new(alpha: f64) -> Self {
        IntervalCache {
            alpha,
            entries: Vec::new(),
        }
    }

    fn get(&mut self, dof: f64, count: f64) -> Interval {
        let key = (dof.to_bits(), count.to_bits());
        if let Some((_, iv)) = self.entries.iter().find(|(k, _)| *k == key) {
            return *iv;
        }
        let iv = chi2_average_interval(self.alpha, dof, count);
        self.entries.push((key, iv));
        iv
    }
}

pub(super) fn summarize(
    name: &str,
    sum: &[f64],
    dof: &[f64],
    count: &[f64],
    variance: SumVariance,
    alpha: f64,
    cache: &mut IntervalCache,
) -> StatisticSummary {
    let steps = sum.len();
    let mut per_step = Vec::with_capacity(steps);
    let mut lower = Vec::with_capacity(steps);
    let mut upper = Vec::with_capacity(steps);
    let mut target = Vec::with_capacity(steps);
    let mut inside = 0usize;
    let mut with_data = 0usize;
    let mut min_step_dof = f64::INFINITY;
    for k in 0..steps {
        if count[k] > 0.0 && dof[k] > 0.0 {
            let avg = sum[k] / count[k];
            let iv = cache.get(dof[k], count[k]);
            with_data += 1;
            if iv.contains(avg) {
                inside += 1;
            }
            min_step_dof = min_step_dof.min(dof[k]);
            per_step.push(Some(avg));
            lower.push(Some(iv.lower));
            upper.push(Some(iv.upper));
            target.push(Some(dof[k] / count[k]));
        } else {
            per_step.push(None);
            lower.push(None);
            upper.push(None);
            target.push(None);
        }
    }
    let total_sum: f64 = sum.iter().sum();
    let total_dof: f64 = dof.iter().sum();
    let total_count: f64 = count.iter().sum();
    let nan_iv = Interval {
        lower: f64::NAN,
        upper: f64::NAN,
    };
    let (time_average, naive, interval, effective_dof, tgt) =
        if total_count > 0.0 && total_dof > 0.0 {
            let naive = chi2_average_interval(alpha, total_dof, total_count);
            let (iv, h) = gate_interval(alpha, total_dof, total_count, variance);
            (
                total_sum / total_count,
                naive,
                iv,
                h,
                total_dof / total_count,
            )
        } else {
            (f64::NAN, nan_iv, nan_iv, 0.0, f64::NAN)
        };
    let power = effective_dof > 0.0 && has_power(alpha, effective_dof);
    let mut verdict = if time_average.is_nan() || interval.lower.is_nan() {
        Verdict::Inconclusive
    } else {
        interval.classify(time_average)
    };
    if verdict == Verdict::Consistent && !power {
        verdict = Verdict::Inconclusive;
    }
    StatisticSummary {
        name: name.to_string(),
        per_step,
        per_step_lower: lower,
        per_step_upper: upper,
        per_step_target: target,
        fraction_in_bounds: if with_data > 0 {
            inside as f64 / with_data as f64
        } else {
            f64::NAN
        },
        steps_with_data: with_data,
        per_step_has_power: min_step_dof.is_finite() && has_power(cache.alpha, min_step_dof),
        time_average,
        target: tgt,
        naive_interval: naive,
        naive_dof: total_dof,
        interval,
        effective_dof,
        run_spread_runs: match variance {
            SumVariance::RunSpread { runs, .. } => Some(runs),
            _ => None,
        },
        batch_spread_batches: match variance {
            SumVariance::BatchSpread { batches, .. } => Some(batches),
            _ => None,
        },
        has_power: power,
        verdict,
    }
}
