//! Consistency statistics: NEES, NIS, their Monte Carlo averages, chi-square acceptance
//! intervals, per-component and whiteness diagnostics, and the verdict.
//!
//! Notation (Bar-Shalom, Li, Kirubarajan 2001, §5.4): over N independent runs,
//! `ANEES_k = (1/N) Σ_i e_ik' P_ik⁻¹ e_ik`, and under a consistent filter
//! `N · ANEES_k ~ χ²(N n_x)`, so its two-sided (1 − α) acceptance interval is
//! `[χ²⁻¹(α/2, N n_x)/N, χ²⁻¹(1 − α/2, N n_x)/N]`. The same holds for ANIS with the
//! dimension of the measurement used at that step.
//!
//! The time-averaged statistics need care. Innovations of a consistent filter are white, so
//! the sum of NIS over all runs and steps is exactly χ² with `Σ N n_z,k` degrees of freedom.
//! Estimation errors are *not* white: `e_k = A_k e_{k−1} + noise` with
//! `A_k = (I − K_k H_k) F_k`, so the sum of NEES over time has the right mean but a larger
//! variance than the naive `χ²(N T n_x)` assumes, and a gate built on the naive interval
//! raises false alarms far more often than α. The engine therefore also accumulates the
//! variance of the per-run NEES sum that the filter itself predicts under consistency
//! (Isserlis' theorem: `Cov(ε_j, ε_k) = 2 tr(P_k⁻¹ Φ_kj P_j Φ_kj')`), and the gate uses a
//! moment-matched scaled chi-square `g·χ²(h)` (Satterthwaite 1946) with that mean and
//! variance. When the errors are uncorrelated this reduces to the naive interval exactly.

mod interval;
mod null_variance;
mod sums;

pub use interval::{
    Interval, SumVariance, Verdict, chi2_average_interval, chi2_inv, combine, gate_alpha,
    gate_interval, has_power, normal_two_sided_quantile, scaled_chi2_interval,
};
pub use null_variance::NeesNullVariance;
pub use sums::{Accumulator, Divergence, StopCause};

use serde::Serialize;
use statrs::distribution::{ContinuousCDF, StudentsT};

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
    /// Whether the per-step tests can detect a factor-2 covariance error (see [`has_power`]).
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
    /// statistic's level ([`ConsistencyReport::statistic_alpha`]).
    pub interval: Interval,
    /// Effective degrees of freedom of [`Self::interval`].
    pub effective_dof: f64,
    /// Set when the interval rests on the spread of this many per-run sums instead of the
    /// filter's prediction (a filter that supplies no error map; see
    /// [`crate::filter::Filter`]); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub run_spread_runs: Option<usize>,
    /// Whether the time-averaged test can detect a factor-2 covariance error.
    pub has_power: bool,
    /// Verdict of the time-averaged test.
    pub verdict: Verdict,
}

/// Normalized error statistic of one state or measurement component: the average of
/// `e_j²/P_jj` (state) or `ν_j²/S_jj` (measurement), target 1.
#[derive(Debug, Clone, Serialize)]
pub struct ComponentStat {
    /// Component name from the problem file.
    pub name: String,
    /// "state" (`e_j²/P_jj`) or "measurement" (`ν_j²/S_jj`).
    pub kind: &'static str,
    /// Average over runs and steps.
    pub value: f64,
    /// Interval around the target 1 from the across-run standard error at level α.
    pub interval: Interval,
    /// Number of (run, step) samples.
    pub samples: f64,
    /// Where the value falls.
    pub verdict: Verdict,
}

/// Normalized autocorrelation of one measurement component's innovations at one lag.
#[derive(Debug, Clone, Serialize)]
pub struct WhitenessStat {
    /// Measurement component name.
    pub component: String,
    /// Lag in steps.
    pub lag: usize,
    /// `Σ u_k u_{k−l} / √(Σ u_k² Σ u_{k−l}²)` with `u = ν_j/√S_jj`; 0 for white innovations.
    pub rho: f64,
    /// Half-width of the (1 − α) band around 0, `z_{1−α/2}/√pairs`.
    pub band: f64,
    /// Number of (run, step) pairs.
    pub pairs: f64,
}

/// Everything `autotune check` reports about one filter.
#[derive(Debug, Clone, Serialize)]
pub struct ConsistencyReport {
    /// Number of Monte Carlo runs N.
    pub runs: usize,
    /// Number of steps T per run.
    pub steps: usize,
    /// Significance level α of the gate: a consistent filter fails with probability ≤ α.
    pub alpha: f64,
    /// Level of each time-averaged gate statistic ([`gate_alpha`]); per-step intervals use α.
    pub statistic_alpha: f64,
    /// NEES statistics (`None` when ground truth is not used).
    pub nees: Option<StatisticSummary>,
    /// NIS statistics.
    pub nis: StatisticSummary,
    /// Per-state-component `e_j²/P_jj`.
    pub state_components: Vec<ComponentStat>,
    /// Per-measurement-component `ν_j²/S_jj`.
    pub measurement_components: Vec<ComponentStat>,
    /// Innovation autocorrelation per component and lag.
    pub whiteness: Vec<WhitenessStat>,
    /// Runs that stopped early (the first few), each with its cause.
    pub divergences: Vec<Divergence>,
    /// Number of runs that stopped early, for any cause.
    pub diverged_runs: usize,
    /// The gate's verdict.
    pub verdict: Verdict,
}

impl ConsistencyReport {
    /// Build the report from the engine's sums. `state_names` and `measurement_names` label
    /// the components; `use_nees` is false in NIS-only mode.
    pub fn from_accumulator(
        acc: &Accumulator,
        alpha: f64,
        state_names: &[String],
        measurement_names: &[String],
        use_nees: bool,
    ) -> Self {
        let mut cache = IntervalCache::new(alpha);
        let gate_alpha = gate_alpha(alpha, if use_nees { 2 } else { 1 });
        let nees = summarize(
            "NEES",
            &acc.nees_sum,
            &acc.nees_dof,
            &acc.nees_count,
            acc.nees_sum_variance(),
            gate_alpha,
            &mut cache,
        );
        let nis_var = 2.0 * acc.nis_dof.iter().sum::<f64>();
        let nis = summarize(
            "NIS",
            &acc.nis_sum,
            &acc.nis_dof,
            &acc.nis_count,
            SumVariance::Predicted(nis_var),
            gate_alpha,
            &mut cache,
        );
        let z = normal_two_sided_quantile(alpha);
        let state_components = components(
            "state",
            state_names,
            ComponentSums {
                total: &acc.state_comp_total,
                run_sum: &acc.state_comp_run_sum,
                run_sq: &acc.state_comp_run_sq,
                samples: &acc.state_comp_samples,
            },
            acc.runs,
            alpha,
        );
        let measurement_components = components(
            "measurement",
            measurement_names,
            ComponentSums {
                total: &acc.meas_comp_total,
                run_sum: &acc.meas_comp_run_sum,
                run_sq: &acc.meas_comp_run_sq,
                samples: &acc.meas_comp_samples,
            },
            acc.meas_comp_runs.iter().copied().max().unwrap_or(0),
            alpha,
        );
        let whiteness = whiteness(acc, measurement_names, z);

        let mut gate = vec![nis.verdict];
        if use_nees {
            gate.push(nees.verdict);
        }
        let verdict = acc.stop_verdict().unwrap_or_else(|| combine(&gate));
        ConsistencyReport {
            runs: acc.runs,
            steps: acc.steps,
            alpha,
            statistic_alpha: gate_alpha,
            nees: use_nees.then_some(nees),
            nis,
            state_components: if use_nees {
                state_components
            } else {
                Vec::new()
            },
            measurement_components,
            whiteness,
            divergences: acc.divergences.clone(),
            diverged_runs: acc.diverged_runs,
            verdict,
        }
    }

    /// Components (state and measurement) sorted from the most to the least inconsistent
    /// by `|ln value|`.
    pub fn worst_components(&self, k: usize) -> Vec<&ComponentStat> {
        let mut all: Vec<&ComponentStat> = self
            .state_components
            .iter()
            .chain(&self.measurement_components)
            .filter(|c| c.value.is_finite() && c.value > 0.0)
            .collect();
        all.sort_by(|a, b| b.value.ln().abs().total_cmp(&a.value.ln().abs()));
        all.truncate(k);
        all
    }
}

/// Chi-square quantiles cost microseconds each; a problem has only a handful of distinct
/// (dof, count) pairs, so compute each once.
struct IntervalCache {
    alpha: f64,
    entries: Vec<((u64, u64), Interval)>,
}

impl IntervalCache {
    fn new(alpha: f64) -> Self {
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

fn summarize(
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
        has_power: power,
        verdict,
    }
}

/// Sums behind one family of component statistics (see [`Accumulator`]).
struct ComponentSums<'a> {
    total: &'a [f64],
    run_sum: &'a [f64],
    run_sq: &'a [f64],
    samples: &'a [f64],
}

/// Per-component averages with an interval from the spread of per-run averages: runs are
/// independent, so the standard error of the mean of per-run time averages is valid however
/// strongly a component's errors are correlated over time.
fn components(
    kind: &'static str,
    names: &[String],
    sums: ComponentSums<'_>,
    runs: usize,
    alpha: f64,
) -> Vec<ComponentStat> {
    let ComponentSums {
        total,
        run_sum,
        run_sq,
        samples,
    } = sums;
    // Student's t with N − 1 degrees of freedom: the spread is estimated from the same N
    // runs (for large N this is the normal quantile).
    let t = if runs >= 2 {
        StudentsT::new(0.0, 1.0, runs as f64 - 1.0)
            .map(|d| d.inverse_cdf(1.0 - alpha / 2.0))
            .unwrap_or_else(|_| normal_two_sided_quantile(alpha))
    } else {
        f64::INFINITY
    };
    names
        .iter()
        .enumerate()
        .map(|(j, name)| {
            let value = if samples[j] > 0.0 {
                total[j] / samples[j]
            } else {
                f64::NAN
            };
            let n = runs as f64;
            let half = if runs >= 2 {
                let mean = run_sum[j] / n;
                let var = ((run_sq[j] - n * mean * mean) / (n - 1.0)).max(0.0);
                t * (var / n).sqrt()
            } else {
                f64::INFINITY
            };
            let interval = Interval {
                lower: 1.0 - half,
                upper: 1.0 + half,
            };
            ComponentStat {
                name: name.clone(),
                kind,
                value,
                interval,
                samples: samples[j],
                verdict: if value.is_nan() {
                    Verdict::Inconclusive
                } else {
                    interval.classify(value)
                },
            }
        })
        .collect()
}

fn whiteness(acc: &Accumulator, names: &[String], z: f64) -> Vec<WhitenessStat> {
    let m = names.len();
    let mut out = Vec::new();
    for lag in 1..=acc.lags {
        for (j, name) in names.iter().enumerate() {
            let idx = (lag - 1) * m + j;
            let pairs = acc.white_pairs[idx];
            if pairs < 1.0 {
                continue;
            }
            let den = (acc.white_a2[idx] * acc.white_b2[idx]).sqrt();
            out.push(WhitenessStat {
                component: name.clone(),
                lag,
                rho: if den > 0.0 {
                    acc.white_ab[idx] / den
                } else {
                    0.0
                },
                band: z / pairs.sqrt(),
                pairs,
            });
        }
    }
    out
}
