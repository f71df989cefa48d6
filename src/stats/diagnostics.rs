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
//!   else. The sum `T_j` of `e_j/√P_jj` (or `ν_j/√S_jj`) over all runs and steps has mean 0;
//!   its variance is `N s²`, with `s²` the sample variance of the N per-run sums, and `z =
//!   T_j/√(N s²)` is judged against Student's t with N − 1 degrees of freedom. Unlike the
//!   variance a consistent filter predicts, the spread holds under a misfit: errors that are
//!   zero-mean but correlated in time (a bias drawn per run, coloured noise) spread the
//!   per-run sums as much as the total (issue 38). The per-run sums of first moments are
//!   near normal (unlike the per-run averages of squares above). With one run there is no
//!   spread: the predicted variance (the sample count for white innovations, the error-map
//!   recursion of [`super::ComponentNullVariance`] for the states) and a normal test.
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
        SumVariance::RunSpread { var, runs: samples }
        | SumVariance::BatchSpread {
            var,
            batches: samples,
        } => {
            let t = StudentsT::new(0.0, 1.0, samples.saturating_sub(1).max(1) as f64)
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
    let sums = LaggedSums {
        pairs: &acc.white_pairs,
        ab: &acc.white_ab,
        a2: &acc.white_a2,
        b2: &acc.white_b2,
    };
    lagged_whiteness(names, acc.lags, &sums, z)
}

/// The lagged sums behind the whiteness statistics of `m` components over lags `1..=L`: at
/// index `(l − 1) m + j`, the pairs of component j at lag l and their sums of `u_k u_{k−l}`,
/// `u_k²` and `u_{k−l}²` (`u = ν_j/√S_jj`). The Monte Carlo sums ([`Accumulator`]) and a
/// field log's (one run) hold them alike.
pub(crate) struct LaggedSums<'a> {
    /// Pairs; a short slice counts no pairs past its end.
    pub pairs: &'a [f64],
    /// `Σ u_k u_{k−l}`.
    pub ab: &'a [f64],
    /// `Σ u_k²`.
    pub a2: &'a [f64],
    /// `Σ u_{k−l}²`.
    pub b2: &'a [f64],
}

/// The lagged autocorrelation `ρ = Σ u_k u_{k−l} / √(Σ u_k² Σ u_{k−l}²)` of each of the
/// components `names`, lag by lag over `1..=lags`, with its band `z/√pairs`; a lag and
/// component without pairs is left out. The one computation of ρ and its band that
/// `check`'s gate and `nis` share.
pub(crate) fn lagged_whiteness(
    names: &[String],
    lags: usize,
    sums: &LaggedSums<'_>,
    z: f64,
) -> Vec<WhitenessStat> {
    let m = names.len();
    let mut out = Vec::new();
    for lag in 1..=lags {
        for (j, name) in names.iter().enumerate() {
            let idx = (lag - 1) * m + j;
            let pairs = sums.pairs.get(idx).copied().unwrap_or(0.0);
            if pairs < 1.0 {
                continue;
            }
            let den = (sums.a2[idx] * sums.b2[idx]).sqrt();
            out.push(WhitenessStat {
                component: name.clone(),
                lag,
                rho: if den > 0.0 { sums.ab[idx] / den } else { 0.0 },
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::{ConsistencyReport, GateSpec};

    /// Upper 5% points of χ²(1..=5) from a printed table (NIST/SEMATECH e-Handbook,
    /// §1.3.6.7.4), to the table's three decimals: an independent reference for the
    /// portmanteau test's threshold.
    const CHI2_95: [f64; 5] = [3.841, 5.991, 7.815, 9.488, 11.070];
    /// Half a unit in the table's last place.
    const TABLE_TOL: f64 = 5e-4;

    fn names(n: usize) -> Vec<String> {
        (0..n).map(|j| format!("z{j}")).collect()
    }

    /// Whiteness sums of two measurement components over `lags` lags: at lag l,
    /// `200 − l` pairs of unit variance with autocorrelation `rho(l, j)`.
    fn white_sums(lags: usize, rho: impl Fn(usize, usize) -> f64) -> Accumulator {
        let mut acc = Accumulator::new(10, 0, 2, lags);
        for lag in 1..=lags {
            for j in 0..2 {
                let idx = (lag - 1) * 2 + j;
                let pairs = (200 - lag) as f64;
                acc.white_pairs[idx] = pairs;
                acc.white_a2[idx] = pairs;
                acc.white_b2[idx] = pairs;
                acc.white_ab[idx] = rho(lag, j) * pairs;
            }
        }
        acc
    }

    #[test]
    fn whiteness_lag_count_covers_lags_one_to_l_for_every_component() {
        let acc = white_sums(4, |lag, j| 0.01 * (lag + 10 * j) as f64);
        let white = whiteness(&acc, &names(2), 1.959964);
        let seen: Vec<(usize, &str)> = white
            .iter()
            .map(|w| (w.lag, w.component.as_str()))
            .collect();
        let want: Vec<(usize, &str)> = (1..=4).flat_map(|lag| [(lag, "z0"), (lag, "z1")]).collect();
        assert_eq!(
            seen, want,
            "lag count: every lag 1..=L (L = 4) of every component, lag-major"
        );
        for w in &white {
            let j = usize::from(w.component == "z1");
            let want_rho = 0.01 * (w.lag + 10 * j) as f64;
            assert!(
                (w.rho - want_rho).abs() < 1e-12,
                "lag {} {}: ρ {} vs {want_rho}",
                w.lag,
                w.component,
                w.rho
            );
            assert_eq!(w.pairs, (200 - w.lag) as f64, "pairs at lag {}", w.lag);
            let band = 1.959964 / ((200 - w.lag) as f64).sqrt();
            assert!((w.band - band).abs() < 1e-12, "band at lag {}", w.lag);
        }
    }

    #[test]
    fn whiteness_rho_normalizes_by_both_sums_of_squares() {
        // Σ ab = 3, Σ a² = 4, Σ b² = 9: ρ = 3 / √36 = 0.5; a lag with no pairs is left out,
        // and one with pairs but zero variance gives ρ = 0.
        let mut acc = Accumulator::new(10, 0, 1, 3);
        (
            acc.white_ab[0],
            acc.white_a2[0],
            acc.white_b2[0],
            acc.white_pairs[0],
        ) = (3.0, 4.0, 9.0, 5.0);
        acc.white_pairs[2] = 2.0;
        let white = whiteness(&acc, &names(1), 2.0);
        assert_eq!(white.len(), 2, "lags with pairs: 1 and 3, {white:?}");
        assert!((white[0].rho - 0.5).abs() < 1e-15, "{white:?}");
        assert_eq!((white[1].lag, white[1].rho), (3, 0.0), "{white:?}");
        assert!((white[0].band - 2.0 / 5f64.sqrt()).abs() < 1e-15);
    }

    #[test]
    fn whiteness_test_degrees_of_freedom_are_the_lags_and_its_threshold_the_chi2_quantile() {
        // Component z0 correlates at the last lag only (ρ_4 = 0.25 over 196 pairs: Q =
        // 196 · 0.0625 = 12.25, above χ²₀.₉₅(4) = 9.488), so a test over lags 1..=3 would
        // miss it; z1 has ρ = 0.1 at every lag (Q = 0.01 · (199 + 198 + 197 + 196) = 7.9,
        // below 9.488 but above χ²₀.₉₅(3) = 7.815: its verdict needs the fourth degree of
        // freedom).
        let acc = white_sums(4, |lag, j| match (lag, j) {
            (4, 0) => 0.25,
            (_, 0) => 0.0,
            _ => 0.1,
        });
        let white = whiteness(&acc, &names(2), 1.959964);
        let tests = whiteness_tests(&white, &names(2), 0.05);
        assert_eq!(tests.len(), 2);
        for t in &tests {
            assert_eq!(t.dof, 4, "{}: degrees of freedom = lag count", t.component);
            assert!(
                (t.threshold - CHI2_95[3]).abs() < TABLE_TOL,
                "{}: threshold {} vs the table's χ²₀.₉₅(4) = {}",
                t.component,
                t.threshold,
                CHI2_95[3]
            );
        }
        assert!((tests[0].statistic - 12.25).abs() < 1e-9, "{:?}", tests[0]);
        assert_eq!(
            tests[0].verdict,
            Verdict::NotWhite,
            "a correlation at the last lag L is tested"
        );
        assert_eq!(tests[0].rho1, 0.0);
        assert!((tests[1].statistic - 7.9).abs() < 1e-9, "{:?}", tests[1]);
        assert_eq!(tests[1].verdict, Verdict::Consistent, "{:?}", tests[1]);
        assert!((tests[1].rho1 - 0.1).abs() < 1e-12, "{:?}", tests[1]);
    }

    #[test]
    fn whiteness_test_thresholds_follow_the_table_for_one_to_five_lags() {
        for lags in 1..=5 {
            let acc = white_sums(lags, |_, _| 0.0);
            let tests = whiteness_tests(&whiteness(&acc, &names(2), 2.0), &names(2), 0.05);
            for t in &tests {
                assert_eq!(t.dof, lags, "lag count: {lags} lags, {} dof", t.dof);
                assert!(
                    (t.threshold - CHI2_95[lags - 1]).abs() < TABLE_TOL,
                    "{lags} lags: threshold {} vs table {}",
                    t.threshold,
                    CHI2_95[lags - 1]
                );
            }
        }
    }

    #[test]
    fn the_full_gate_tests_whiteness_over_all_lags() {
        // The gate's own report: one portmanteau test per measurement component, over the
        // accumulator's L = 4 lags (χ²(4)), at the gate's Šidák level (3 tests: 0.017, a
        // threshold near 12.1; ρ_4 = 0.3 over 196 pairs gives Q = 17.64).
        let acc = white_sums(4, |lag, j| if (lag, j) == (4, 0) { 0.3 } else { 0.0 });
        let r =
            ConsistencyReport::from_accumulator(&acc, &GateSpec::full(0.05, false), &[], &names(2));
        assert_eq!(r.whiteness.len(), 8, "lag count: 4 lags × 2 components");
        assert_eq!(
            r.whiteness_tests.iter().map(|t| t.dof).collect::<Vec<_>>(),
            vec![4, 4],
            "whiteness degrees of freedom"
        );
        assert_eq!(r.whiteness_tests[0].verdict, Verdict::NotWhite);
        assert!(!r.verdict.passes(), "{:?}", r.verdict);
    }
}
