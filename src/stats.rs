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

use nalgebra::{Cholesky, DMatrix, Dyn};
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF, Normal, StudentsT};

use crate::montecarlo::Accumulator;

/// Inverse of the chi-square CDF: the `p` quantile of `χ²(dof)`.
///
/// `dof` may be fractional (for moment-matched approximations). Panics only if `dof` is
/// not positive and finite, which callers rule out.
pub fn chi2_inv(p: f64, dof: f64) -> f64 {
    ChiSquared::new(dof)
        .expect("chi-square degrees of freedom must be positive and finite")
        .inverse_cdf(p)
}

/// Streaming computation of the variance of one run's NEES sum `Σ_k ε_k` that a filter
/// predicts for itself if it is consistent.
///
/// Under consistency `e_k = A_k e_{k−1} + (noise independent of e_{k−1})`, so
/// `E[e_k e_j'] = Φ_kj P_j` with `Φ_kj = A_k ⋯ A_{j+1}`, and for jointly Gaussian errors
/// `Cov(ε_j, ε_k) = 2 tr(P_k⁻¹ Φ_kj P_j Φ_kj')`. Summing over `j < k` gives
/// `2 tr(P_k⁻¹ G_k)` with `G_k = A_k (G_{k−1} + P_{k−1}) A_k'`, `G_1 = 0`, hence
/// `Var(Σ_k ε_k) = Σ_k [2 n_x + 4 tr(P_k⁻¹ G_k)]`, in O(n³) per step.
#[derive(Debug, Clone)]
pub struct NeesNullVariance {
    n: usize,
    g: DMatrix<f64>,
    p_prev: Option<DMatrix<f64>>,
    var: f64,
}

impl NeesNullVariance {
    /// Start a run with state dimension `n`.
    pub fn new(n: usize) -> Self {
        NeesNullVariance {
            n,
            g: DMatrix::zeros(n, n),
            p_prev: None,
            var: 0.0,
        }
    }

    /// Add step k: its error map `A_k` (n × n), posterior covariance `P_k` and the
    /// Cholesky factor of `P_k`.
    /// Returns this step's contribution to the variance.
    pub fn step(&mut self, a: &DMatrix<f64>, p: &DMatrix<f64>, chol: &Cholesky<f64, Dyn>) -> f64 {
        if let Some(pp) = &self.p_prev {
            self.g = a * (&self.g + pp) * a.transpose();
        }
        let cross = chol.solve(&self.g).trace();
        let inc = 2.0 * self.n as f64 + 4.0 * cross;
        self.var += inc;
        self.p_prev = Some(p.clone());
        inc
    }

    /// Add `steps` more steps that each contribute `inc` (steady state).
    pub fn extend_steady(&mut self, inc: f64, steps: usize) {
        self.var += inc * steps as f64;
    }

    /// The predicted variance of the NEES sum so far.
    pub fn variance(&self) -> f64 {
        self.var
    }
}

/// A closed acceptance interval `[lower, upper]` for an averaged statistic.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Interval {
    /// Lower bound `r1`.
    pub lower: f64,
    /// Upper bound `r2`.
    pub upper: f64,
}

impl Interval {
    /// Whether `v` lies inside the interval (bounds included).
    pub fn contains(&self, v: f64) -> bool {
        v >= self.lower && v <= self.upper
    }

    /// Where `v` lies relative to the interval.
    pub fn classify(&self, v: f64) -> Verdict {
        if v > self.upper {
            Verdict::Overconfident
        } else if v < self.lower {
            Verdict::Underconfident
        } else {
            Verdict::Consistent
        }
    }
}

/// The two-sided (1 − α) interval of an average of `count` chi-square variables whose
/// degrees of freedom add up to `total_dof`: `[χ²⁻¹(α/2, D)/count, χ²⁻¹(1 − α/2, D)/count]`.
pub fn chi2_average_interval(alpha: f64, total_dof: f64, count: f64) -> Interval {
    Interval {
        lower: chi2_inv(alpha / 2.0, total_dof) / count,
        upper: chi2_inv(1.0 - alpha / 2.0, total_dof) / count,
    }
}

/// The two-sided (1 − α) interval of `sum / count`, where `sum` has mean `mean` and
/// variance `var`, approximated by the scaled chi-square `g·χ²(h)` with the same two
/// moments: `g = var / (2 mean)`, `h = 2 mean² / var`. Returns the interval and `h`.
pub fn scaled_chi2_interval(alpha: f64, mean: f64, var: f64, count: f64) -> (Interval, f64) {
    let g = var / (2.0 * mean);
    let h = 2.0 * mean * mean / var;
    let iv = Interval {
        lower: g * chi2_inv(alpha / 2.0, h) / count,
        upper: g * chi2_inv(1.0 - alpha / 2.0, h) / count,
    };
    (iv, h)
}

/// Whether a two-sided chi-square test on `dof` degrees of freedom at level α can tell a
/// covariance that is off by a factor of two from a correct one: both `χ²⁻¹(1 − α/2)/dof`
/// below 2 and `χ²⁻¹(α/2)/dof` above 1/2. At α = 0.05 this needs 23 degrees of freedom; a
/// single run of a scalar measurement has one.
pub fn has_power(alpha: f64, dof: f64) -> bool {
    dof > 0.0
        && chi2_inv(1.0 - alpha / 2.0, dof) / dof < 2.0
        && chi2_inv(alpha / 2.0, dof) / dof > 0.5
}

/// The two-sided standard-normal quantile `z_{1−α/2}`.
pub fn normal_two_sided_quantile(alpha: f64) -> f64 {
    Normal::standard().inverse_cdf(1.0 - alpha / 2.0)
}

/// The outcome of a consistency test.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Inside the acceptance interval.
    Consistent,
    /// Errors larger than the filter believes (statistic above `r2`): its P or S is too
    /// small; increase Q (or R if the sensor model is wrong).
    Overconfident,
    /// Errors smaller than the filter believes (statistic below `r1`): decrease Q.
    Underconfident,
    /// Some statistics above their interval, some below.
    Mixed,
    /// Passed, but with too few degrees of freedom for the test to mean anything.
    Inconclusive,
    /// The filter's covariance stopped being positive definite.
    Diverged,
}

impl Verdict {
    /// Whether this verdict lets a CI gate pass.
    pub fn passes(self) -> bool {
        self == Verdict::Consistent
    }

    /// Short human wording.
    pub fn describe(self) -> &'static str {
        match self {
            Verdict::Consistent => "consistent",
            Verdict::Overconfident => {
                "overconfident (errors larger than the filter believes: increase Q)"
            }
            Verdict::Underconfident => {
                "underconfident (errors smaller than the filter believes: decrease Q)"
            }
            Verdict::Mixed => "inconsistent (some statistics too high, some too low)",
            Verdict::Inconclusive => "inconclusive (too little data for the test to have power)",
            Verdict::Diverged => "diverged (covariance not positive definite)",
        }
    }

    /// One-word label.
    pub fn label(self) -> &'static str {
        match self {
            Verdict::Consistent => "consistent",
            Verdict::Overconfident => "overconfident",
            Verdict::Underconfident => "underconfident",
            Verdict::Mixed => "mixed",
            Verdict::Inconclusive => "inconclusive",
            Verdict::Diverged => "diverged",
        }
    }
}

/// The level of each of `k` gate statistics so that a consistent filter fails the gate with
/// probability at most α (Šidák): `1 − (1 − α)^{1/k}`. Exactly α when the statistics are
/// independent, less when they are positively dependent (NEES and NIS are).
pub fn gate_alpha(alpha: f64, k: usize) -> f64 {
    1.0 - (1.0 - alpha).powf(1.0 / k.max(1) as f64)
}

/// Combine the verdicts of several statistics into one.
pub fn combine(verdicts: &[Verdict]) -> Verdict {
    if verdicts.contains(&Verdict::Diverged) {
        return Verdict::Diverged;
    }
    let over = verdicts.contains(&Verdict::Overconfident);
    let under = verdicts.contains(&Verdict::Underconfident);
    match (over, under) {
        (true, true) => Verdict::Mixed,
        (true, false) => Verdict::Overconfident,
        (false, true) => Verdict::Underconfident,
        _ if verdicts.contains(&Verdict::Mixed) => Verdict::Mixed,
        _ if verdicts.contains(&Verdict::Inconclusive) => Verdict::Inconclusive,
        _ => Verdict::Consistent,
    }
}

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

/// A run in which the filter's covariance stopped being positive definite.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Divergence {
    /// Run index (0-based).
    pub run: usize,
    /// Time step (1-based).
    pub step: usize,
    /// What failed.
    pub reason: String,
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
    /// Runs whose filter diverged (the first few).
    pub divergences: Vec<Divergence>,
    /// Number of runs whose filter diverged.
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
            acc.nees_null_variance(),
            gate_alpha,
            &mut cache,
        );
        let nis_var = 2.0 * acc.nis_dof.iter().sum::<f64>();
        let nis = summarize(
            "NIS",
            &acc.nis_sum,
            &acc.nis_dof,
            &acc.nis_count,
            nis_var,
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
        let mut verdict = combine(&gate);
        if acc.diverged_runs > 0 {
            verdict = Verdict::Diverged;
        }
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
    null_var: f64,
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
            // The predicted variance can never be below the independent-steps value 2·D; guard
            // against rounding pushing it there.
            let var = null_var.max(2.0 * total_dof);
            let (iv, h) = scaled_chi2_interval(alpha, total_dof, var, total_count);
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
    let mut verdict = if time_average.is_nan() {
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

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn average_interval_scales_by_count() {
        // N = 50 runs of a 2-D statistic: 100 degrees of freedom, divided by 50.
        let iv = chi2_average_interval(0.05, 100.0, 50.0);
        assert_relative_eq!(
            iv.lower,
            chi2_inv(0.025, 100.0) / 50.0,
            max_relative = 1e-15
        );
        assert_relative_eq!(
            iv.upper,
            chi2_inv(0.975, 100.0) / 50.0,
            max_relative = 1e-15
        );
        assert!(iv.lower < 2.0 && iv.upper > 2.0);
    }

    #[test]
    fn scaled_interval_reduces_to_chi2_without_correlation() {
        let (iv, h) = scaled_chi2_interval(0.05, 400.0, 800.0, 100.0);
        let naive = chi2_average_interval(0.05, 400.0, 100.0);
        assert_relative_eq!(h, 400.0, max_relative = 1e-14);
        assert_relative_eq!(iv.lower, naive.lower, max_relative = 1e-12);
        assert_relative_eq!(iv.upper, naive.upper, max_relative = 1e-12);
    }

    #[test]
    fn scaled_interval_widens_with_variance() {
        let (iv, h) = scaled_chi2_interval(0.05, 400.0, 8000.0, 100.0);
        let naive = chi2_average_interval(0.05, 400.0, 100.0);
        assert_relative_eq!(h, 40.0, max_relative = 1e-14);
        assert!(iv.lower < naive.lower && iv.upper > naive.upper);
    }

    #[test]
    fn nees_null_variance_matches_brute_force_double_sum() {
        // Scalar AR(1) error e_k = a e_{k-1} + w with stationary variance p: the NEES
        // ε_k = e_k²/p has Cov(ε_j, ε_k) = 2 a^{2|k-j|}, so Var(Σ ε) = Σ_j Σ_k 2 a^{2|k-j|}.
        let (a, p, t) = (0.8_f64, 3.0_f64, 25usize);
        let am = DMatrix::from_element(1, 1, a);
        let pm = DMatrix::from_element(1, 1, p);
        let chol = Cholesky::new(pm.clone()).unwrap();
        let mut nv = NeesNullVariance::new(1);
        for _ in 0..t {
            nv.step(&am, &pm, &chol);
        }
        let mut want = 0.0;
        for j in 0..t {
            for k in 0..t {
                want += 2.0 * a.powi(2 * (j as i32 - k as i32).abs());
            }
        }
        assert_relative_eq!(nv.variance(), want, max_relative = 1e-12);
    }

    #[test]
    fn gate_alpha_splits_the_level() {
        assert_relative_eq!(gate_alpha(0.05, 1), 0.05, max_relative = 1e-15);
        let a = gate_alpha(0.05, 2);
        assert_relative_eq!(1.0 - (1.0 - a) * (1.0 - a), 0.05, max_relative = 1e-12);
    }

    #[test]
    fn power_threshold() {
        // One run of a scalar measurement cannot see a factor-2 error; 50 degrees of freedom can.
        assert!(!has_power(0.05, 1.0));
        assert!(!has_power(0.05, 4.0));
        assert!(has_power(0.05, 50.0));
    }

    #[test]
    fn classify_and_combine() {
        let iv = Interval {
            lower: 0.5,
            upper: 1.5,
        };
        assert_eq!(iv.classify(2.0), Verdict::Overconfident);
        assert_eq!(iv.classify(0.1), Verdict::Underconfident);
        assert_eq!(iv.classify(1.0), Verdict::Consistent);
        assert_eq!(
            combine(&[Verdict::Consistent, Verdict::Overconfident]),
            Verdict::Overconfident
        );
        assert_eq!(
            combine(&[Verdict::Underconfident, Verdict::Overconfident]),
            Verdict::Mixed
        );
        assert_eq!(
            combine(&[Verdict::Consistent, Verdict::Inconclusive]),
            Verdict::Inconclusive
        );
        assert_eq!(
            combine(&[Verdict::Consistent, Verdict::Consistent]),
            Verdict::Consistent
        );
    }
}
