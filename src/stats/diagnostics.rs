//! The diagnostics beside the time averages, which the full gate also tests: per-component
//! normalized errors and the whiteness of each measurement component's innovations.
//!
//! - Component j: the average `c_j` of `e_j²/P_jj` (or `ν_j²/S_jj`) is 1 under consistency,
//!   and its sum over all runs and steps has as many degrees of freedom as samples. The
//!   innovations of a consistent filter are white, so a measurement component's sum is
//!   exactly χ²; a state component's errors are correlated over time, and the variance of
//!   its sum is what the filter predicts from its error map (Isserlis, as for the NEES:
//!   [`super::ComponentNullVariance`]), or without a map the spread of the per-run sums. The
//!   spread of per-run averages alone will not do: a slowly varying component (a bias, a
//!   heading) has per-run averages as heavy-tailed as `χ²(ν)/ν` with ν of one or two, whose
//!   sample variance over some tens of runs is usually far too small, and a t test on them
//!   rejects several times more often than its level (measured on ins_gnss: 14–16 of 100 seeds
//!   at the truth for a family-wise 0.05).
//! - Zero mean of component j: consistency (Bar-Shalom, Li, Kirubarajan 2001, §5.4) is
//!   zero-mean errors *and* the stated covariance, and a constant bias the filter does not
//!   model (a sensor offset, an unmodelled input) shows in the first moment before anything
//!   else. The sum `T_j` of `e_j/√P_jj` (or `ν_j/√S_jj`) over all runs and steps has mean 0
//!   and, under consistency, the variance the filter predicts: the sample count for the
//!   white innovations, the error-map recursion of [`super::ComponentNullVariance`] for the
//!   correlated state errors (or the run-to-run spread of the per-run sums without a map,
//!   then judged against Student's t with N − 1 degrees of freedom). The test is two-sided
//!   normal on `z = T_j/√Var(T_j)`.
//! - Whiteness of component j: an optimal filter's innovations are uncorrelated in time, so
//!   with `u = ν_j/√S_jj` the pooled lag-l autocorrelation `ρ_l` is about N(0, 1/pairs_l),
//!   independently across lags; the portmanteau `Q_j = Σ_l pairs_l ρ_l²` (Box and Pierce
//!   1970, pooled over runs) is then χ² with one degree of freedom per lag.

use serde::Serialize;

use statrs::distribution::{ContinuousCDF, StudentsT};

use super::{
    Accumulator, Interval, SumVariance, Verdict, chi2_inv, gate_interval, normal_two_sided_quantile,
};

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
    /// Average of `e_j/√P_jj` (state) or `ν_j/√S_jj` (measurement) over the samples: 0 for
    /// a consistent filter, in standard deviations (NaN when the data give no sign).
    pub mean: f64,
    /// The zero-mean test's statistic: the sum over all runs and steps divided by the
    /// square root of its null variance (NaN when there is no test).
    pub mean_z: f64,
    /// The zero-mean test's verdict: [`Verdict::Biased`] when `|mean_z|` exceeds the test's
    /// threshold, [`Verdict::Inconclusive`] without a test.
    pub mean_verdict: Verdict,
}

/// The first-moment data of one component: the sum over runs and steps, the samples behind
/// it, and what its null variance rests on.
pub(super) struct MeanSums {
    pub total: f64,
    pub samples: f64,
    pub variance: SumVariance,
    /// The average of the squares (the component's `value`).
    pub second_moment: f64,
}

/// The zero-mean test of a component at `level`: `(mean, z, verdict)`.
pub(super) fn mean_test(m: &MeanSums, level: f64) -> (f64, f64, Verdict) {
    if m.samples <= 0.0 {
        return (f64::NAN, f64::NAN, Verdict::Inconclusive);
    }
    let mean = m.total / m.samples;
    let (var, threshold) = match m.variance {
        // A covariance that is off (caught by the second-moment test) scales the spread of
        // the sum with it; widening by the observed variance about the mean, never
        // narrowing, keeps a filter with too small an R from being called biased, and costs
        // nothing under consistency or against a bias (the mean is taken out).
        SumVariance::Predicted(v) => (
            v * (m.second_moment - mean * mean).max(1.0),
            normal_two_sided_quantile(level),
        ),
        SumVariance::RunSpread { var, runs } => {
            let t = StudentsT::new(0.0, 1.0, runs.saturating_sub(1).max(1) as f64)
                .map(|d| d.inverse_cdf(1.0 - level / 2.0))
                .unwrap_or(f64::INFINITY);
            (var, t)
        }
        SumVariance::Unavailable => (f64::NAN, f64::NAN),
    };
    if var.is_nan() || var <= 0.0 || !var.is_finite() || !m.total.is_finite() {
        return (mean, f64::NAN, Verdict::Inconclusive);
    }
    let z = m.total / var.sqrt();
    let verdict = if z.abs() > threshold {
        Verdict::Biased
    } else {
        Verdict::Consistent
    };
    (mean, z, verdict)
}

impl ComponentStat {
    /// Whether a failed zero-mean test explains this component: its second moment, less the
    /// square of its mean, falls inside the second-moment interval (a bias b adds b² to
    /// `E[y²] = 1`), or the second moment passed anyway. A mean far smaller than the
    /// second moment's excess (a filter lagging under too small a Q) is a symptom instead.
    pub fn bias_explains(&self) -> bool {
        self.mean_verdict == Verdict::Biased
            && self.mean_z.is_finite()
            && (!matches!(
                self.verdict,
                Verdict::Overconfident | Verdict::Underconfident
            ) || self.interval.contains(self.value - self.mean * self.mean))
    }
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

/// The portmanteau whiteness test of one measurement component's innovations over lags
/// 1..L.
#[derive(Debug, Clone, Serialize)]
pub struct WhitenessTest {
    /// Measurement component name.
    pub component: String,
    /// `Q = Σ_l pairs_l ρ_l²` over the lags with pairs.
    pub statistic: f64,
    /// Its degrees of freedom: the lags with pairs.
    pub dof: usize,
    /// The test's upper bound `χ²⁻¹(1 − level, dof)` at the level it was run at.
    pub threshold: f64,
    /// The lag-1 autocorrelation (the sign says which way the model is off).
    pub rho1: f64,
    /// Consistent, or [`Verdict::NotWhite`] above the threshold.
    pub verdict: Verdict,
}

/// Per-component averages, each with a two-sided interval at level `alpha` around 1: the
/// gate interval ([`gate_interval`]) of the component's sum over all runs and steps, whose
/// mean is its number of samples and whose variance is `variance(j)`; and the zero-mean
/// test of `means(j)` at level `mean_alpha`.
pub(super) fn components(
    kind: &'static str,
    names: &[String],
    total: &[f64],
    samples: &[f64],
    variance: impl Fn(usize) -> SumVariance,
    means: impl Fn(usize) -> MeanSums,
    (alpha, mean_alpha): (f64, f64),
) -> Vec<ComponentStat> {
    names
        .iter()
        .enumerate()
        .map(|(j, name)| {
            let (value, interval) = if samples[j] > 0.0 {
                let iv = gate_interval(alpha, samples[j], samples[j], variance(j)).0;
                (total[j] / samples[j], iv)
            } else {
                let nan = Interval {
                    lower: f64::NAN,
                    upper: f64::NAN,
                };
                (f64::NAN, nan)
            };
            let (mean, mean_z, mean_verdict) = mean_test(&means(j), mean_alpha);
            ComponentStat {
                mean,
                mean_z,
                mean_verdict,
                name: name.clone(),
                kind,
                value,
                interval,
                samples: samples[j],
                verdict: if value.is_nan() || interval.lower.is_nan() {
                    Verdict::Inconclusive
                } else {
                    interval.classify(value)
                },
            }
        })
        .collect()
}

pub(super) fn whiteness(acc: &Accumulator, names: &[String], z: f64) -> Vec<WhitenessStat> {
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

/// The portmanteau test of each measurement component over the lags in `white` (the
/// per-lag statistics of [`whiteness`]), at `level`; components without pairs get none.
pub fn whiteness_tests(
    white: &[WhitenessStat],
    names: &[String],
    level: f64,
) -> Vec<WhitenessTest> {
    names
        .iter()
        .filter_map(|name| {
            let lags: Vec<&WhitenessStat> = white.iter().filter(|w| &w.component == name).collect();
            if lags.is_empty() {
                return None;
            }
            let statistic: f64 = lags.iter().map(|w| w.pairs * w.rho * w.rho).sum();
            let dof = lags.len();
            let threshold = chi2_inv(1.0 - level, dof as f64);
            Some(WhitenessTest {
                component: name.clone(),
                statistic,
                dof,
                threshold,
                rho1: lags.iter().find(|w| w.lag == 1).map_or(0.0, |w| w.rho),
                verdict: if statistic > threshold {
                    Verdict::NotWhite
                } else {
                    Verdict::Consistent
                },
            })
        })
        .collect()
}

/// The gate's tests of `report` as standard normal deviates under consistency, one per
/// test the gate applies (for the mean gate: the time averages only): a time average or
/// component `v` with target `d` and interval `[a, b]` at the test level ℓ gives
/// `z_{1−ℓ/2} (v − d)/(b − d)` above the target and `z_{1−ℓ/2} (v − d)/(d − a)` below it, so
/// that the interval's ends are ±`z_{1−ℓ/2}`; each whiteness lag gives `√pairs · ρ_l`. A
/// filter passes the gate with probability about 1 − α when every entry is near 0, and the
/// sum of squares is what a search must drive down to land where the gate passes.
pub fn gate_deviates(report: &super::ConsistencyReport) -> Vec<f64> {
    let z = super::normal_two_sided_quantile(report.statistic_alpha);
    let scaled = |v: f64, d: f64, iv: &Interval| {
        let half = if v >= d { iv.upper - d } else { d - iv.lower };
        if half > 0.0 && v.is_finite() {
            z * (v - d) / half
        } else {
            0.0
        }
    };
    let mut out = Vec::new();
    for s in report.nees.iter().chain(std::iter::once(&report.nis)) {
        if s.steps_with_data > 0 {
            out.push(scaled(s.time_average, s.target, &s.interval));
        }
    }
    if report.gate == super::GateMode::Full {
        for c in report
            .state_components
            .iter()
            .chain(&report.measurement_components)
        {
            if c.samples > 0.0 && c.interval.lower.is_finite() {
                out.push(scaled(c.value, 1.0, &c.interval));
            }
        }
        out.extend(report.whiteness.iter().map(|w| w.pairs.sqrt() * w.rho));
    }
    out
}
