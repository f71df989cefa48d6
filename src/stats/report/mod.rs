//! The consistency report: the engine's sums judged by the gate (the time averages against
//! their chi-square intervals, the components and whiteness at the gate's levels), the
//! verdict and the diagnosis of which of Q and R is off.

use serde::Serialize;

use super::attribution::{Diagnosis, Evidence, diagnose_components};
use super::diagnostics::{
    ComponentStat, MeanSums, WhitenessStat, WhitenessTest, components, whiteness, whiteness_tests,
};
use super::interval::{
    GateMode, Interval, SumVariance, Verdict, combine, gate_alpha, normal_two_sided_quantile,
};
use super::sums::{Accumulator, Divergence};

mod summary;

pub use summary::StatisticSummary;
use summary::{IntervalCache, summarize};

/// Everything `autotune check` reports about one filter.
#[derive(Debug, Clone, Serialize)]
pub struct ConsistencyReport {
    /// Number of Monte Carlo runs N.
    pub runs: usize,
    /// Number of steps T per run.
    pub steps: usize,
    /// Significance level α of the gate: a consistent filter fails with probability ≤ α.
    pub alpha: f64,
    /// Which tests the gate applies.
    pub gate: GateMode,
    /// How many tests the gate applies (the time averages, and in the full gate every
    /// component's second moment and zero mean, and every measurement component's
    /// whiteness).
    pub tests: usize,
    /// Level of each gate test but the zero-mean ones, `1 − (1 − α)^{1/k}` (Šidák) with k the
    /// tests when the zero-mean tests count as one, so that a consistent filter fails the
    /// whole gate with probability at most α; per-step intervals use α.
    pub statistic_alpha: f64,
    /// Level of each zero-mean test: together they take one Šidák share, split evenly
    /// (Bonferroni) among them. A bias moves the mean by many standard errors, so the mean
    /// tests keep their power at a smaller level, and the second-moment tests keep nearly
    /// the level they had without them (their power at a ±10% Q or R error is what a gate
    /// is bought for).
    pub mean_alpha: f64,
    /// NEES statistics (`None` when ground truth is not used).
    pub nees: Option<StatisticSummary>,
    /// NIS statistics.
    pub nis: StatisticSummary,
    /// Per-state-component `e_j²/P_jj`.
    pub state_components: Vec<ComponentStat>,
    /// Per-measurement-component `ν_j²/S_jj`.
    pub measurement_components: Vec<ComponentStat>,
    /// Innovation autocorrelation per component and lag, each with the band of a white
    /// sequence at level α (a diagnostic).
    pub whiteness: Vec<WhitenessStat>,
    /// The portmanteau whiteness test of each measurement component over all lags, at the
    /// gate's level in the full gate (at α as a diagnostic in the mean gate).
    pub whiteness_tests: Vec<WhitenessTest>,
    /// Runs that stopped early (the first few), each with its cause.
    pub divergences: Vec<Divergence>,
    /// Number of runs that stopped early, for any cause.
    pub diverged_runs: usize,
    /// The gate's verdict.
    pub verdict: Verdict,
    /// Which of Q and R the components and whiteness point to (see `diagnose`).
    pub diagnosis: Diagnosis,
}

/// How the gate tests a filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GateSpec {
    /// Family-wise significance level α in (0, 1): a consistent filter fails the gate with
    /// probability at most α.
    pub alpha: f64,
    /// Which tests.
    pub mode: GateMode,
    /// Whether the ground truth is used (NEES and the state components); false judges by
    /// the innovations alone.
    pub use_nees: bool,
}

impl GateSpec {
    /// The default gate (every test the summary shows) at family-wise level `alpha`.
    pub fn full(alpha: f64, use_nees: bool) -> Self {
        GateSpec {
            alpha,
            mode: GateMode::Full,
            use_nees,
        }
    }
}

impl ConsistencyReport {
    /// Build the report from the engine's sums. `state_names` and `measurement_names` label
    /// the components.
    ///
    /// The gate applies k tests (the time-averaged ANIS, ANEES with the truth; in the full
    /// gate also each component with samples, twice: its second moment and its zero mean,
    /// and each measurement component's whiteness),
    /// each at the Šidák level `1 − (1 − α)^{1/k}`: exactly α family-wise if the tests were
    /// independent, less since they are positively dependent (a filter off in one component
    /// is off in the time averages too).
    pub fn from_accumulator(
        acc: &Accumulator,
        gate: &GateSpec,
        state_names: &[String],
        measurement_names: &[String],
    ) -> Self {
        let (alpha, use_nees, full) = (gate.alpha, gate.use_nees, gate.mode == GateMode::Full);
        let white = whiteness(acc, measurement_names, normal_two_sided_quantile(alpha));
        let levels = GateLevels::of(acc, gate, &white, measurement_names);
        let (tests, level, diagnostic_level, mean_level) = (
            levels.tests,
            levels.level,
            levels.diagnostic_level,
            levels.mean_level,
        );
        let mut cache = IntervalCache::new(alpha);
        let nees = summarize(
            "NEES",
            &acc.nees_sum,
            &acc.nees_dof,
            &acc.nees_count,
            acc.nees_sum_variance(),
            level,
            &mut cache,
        );
        let nis_var = 2.0 * acc.nis_dof.iter().sum::<f64>();
        let nis = summarize(
            "NIS",
            &acc.nis_sum,
            &acc.nis_dof,
            &acc.nis_count,
            SumVariance::Predicted(nis_var),
            level,
            &mut cache,
        );
        let (state_components, measurement_components) = component_stats(
            acc,
            state_names,
            measurement_names,
            (diagnostic_level, mean_level),
        );
        let whiteness_tests = whiteness_tests(&white, measurement_names, diagnostic_level);
        let state_components = if use_nees {
            state_components
        } else {
            Vec::new()
        };

        let verdicts = gate_verdicts(
            (&nis, use_nees.then_some(&nees)),
            &state_components,
            &measurement_components,
            &whiteness_tests,
            full,
        );
        let bias_explains_all =
            full && bias_explains_all(&state_components, &measurement_components);
        let verdict = acc.stop_verdict().unwrap_or_else(|| {
            if bias_explains_all {
                Verdict::Biased
            } else {
                combine(&verdicts)
            }
        });
        let mut report = ConsistencyReport {
            runs: acc.runs,
            steps: acc.steps,
            alpha,
            gate: gate.mode,
            tests,
            statistic_alpha: level,
            mean_alpha: mean_level,
            nees: use_nees.then_some(nees),
            nis,
            state_components,
            measurement_components,
            whiteness: white,
            whiteness_tests,
            divergences: acc.divergences.clone(),
            diverged_runs: acc.diverged_runs,
            verdict,
            diagnosis: Diagnosis {
                findings: Vec::new(),
                suspect: None,
                states_off_too: false,
            },
        };
        // Runs that stopped early leave numbers no diagnosis can rest on.
        if !verdict.passes() && acc.stop_verdict().is_none() {
            report.diagnosis = diagnose(&report);
        }
        report
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

/// The gate's number of tests and its levels: each second-moment test at the Šidák level
/// of α over the tests, the zero-mean tests sharing one Šidák slot (Bonferroni within it);
/// in the mean gate the components and whiteness are diagnostics, judged at α.
struct GateLevels {
    tests: usize,
    level: f64,
    diagnostic_level: f64,
    mean_level: f64,
}

impl GateLevels {
    fn of(
        acc: &Accumulator,
        gate: &GateSpec,
        white: &[WhitenessStat],
        measurement_names: &[String],
    ) -> Self {
        let (alpha, use_nees, full) = (gate.alpha, gate.use_nees, gate.mode == GateMode::Full);
        let has = |samples: &[f64]| samples.iter().filter(|&&s| s > 0.0).count();
        let white_components = measurement_names
            .iter()
            .filter(|n| white.iter().any(|w| &w.component == *n))
            .count();
        // Each component with samples brings two tests: its second moment and its mean.
        let tests = if full {
            1 + usize::from(use_nees)
                + if use_nees {
                    has(&acc.state_comp_samples) + has(&acc.state_mean_samples)
                } else {
                    0
                }
                + 2 * has(&acc.meas_comp_samples)
                + white_components
        } else {
            1 + usize::from(use_nees)
        };
        let mean_tests = if full {
            has(&acc.meas_comp_samples)
                + if use_nees {
                    has(&acc.state_mean_samples)
                } else {
                    0
                }
        } else {
            0
        };
        let level = gate_alpha(alpha, tests - mean_tests + usize::from(mean_tests > 0));
        // In the mean gate the components and whiteness are diagnostics, judged at α.
        let diagnostic_level = if full { level } else { alpha };
        let mean_level = if mean_tests > 0 {
            level / mean_tests as f64
        } else {
            diagnostic_level
        };
        GateLevels {
            tests,
            level,
            diagnostic_level,
            mean_level,
        }
    }
}

/// Each state and measurement component's second-moment and zero-mean statistics, judged
/// at `levels` (the second moments', the means').
fn component_stats(
    acc: &Accumulator,
    state_names: &[String],
    measurement_names: &[String],
    levels: (f64, f64),
) -> (Vec<ComponentStat>, Vec<ComponentStat>) {
    let state_components = components(
        "state",
        state_names,
        &acc.state_comp_total,
        &acc.state_comp_samples,
        |j| acc.state_component_variance(j),
        |j| MeanSums {
            total: acc.state_mean_total[j],
            samples: acc.state_mean_samples[j],
            variance: acc.state_mean_variance(j),
            second_moment: acc.state_comp_total[j] / acc.state_comp_samples[j],
        },
        levels,
    );
    // White under consistency: each ν_j²/S_jj is an independent χ²(1).
    let measurement_components = components(
        "measurement",
        measurement_names,
        &acc.meas_comp_total,
        &acc.meas_comp_samples,
        |j| SumVariance::Predicted(2.0 * acc.meas_comp_samples[j]),
        // The run-to-run spread, as for the states (white under consistency, but not under a
        // misfit, where the sample count would understate the variance).
        |j| MeanSums {
            total: acc.meas_mean_total[j],
            samples: acc.meas_comp_samples[j],
            variance: acc.meas_mean_variance(j),
            second_moment: acc.meas_comp_total[j] / acc.meas_comp_samples[j],
        },
        levels,
    );
    (state_components, measurement_components)
}

/// The verdicts the gate combines: NIS (and NEES with the truth); in the full gate also
/// each component with samples, each zero-mean test with a statistic, and each whiteness
/// test.
fn gate_verdicts(
    (nis, nees): (&StatisticSummary, Option<&StatisticSummary>),
    state_components: &[ComponentStat],
    measurement_components: &[ComponentStat],
    whiteness_tests: &[WhitenessTest],
    full: bool,
) -> Vec<Verdict> {
    // A statistic without data (no innovations in a record of errors, no errors in one
    // of innovations) or a component whose spread the data cannot give (one run of a
    // filter without an error map) is no test: it does not make the gate inconclusive.
    // With no test at all, the gate is.
    let mut verdicts: Vec<Verdict> = std::iter::once(nis)
        .chain(nees)
        .filter(|s| s.steps_with_data > 0)
        .map(|s| s.verdict)
        .collect();
    if verdicts.is_empty() {
        return vec![Verdict::Inconclusive];
    }
    if full {
        verdicts.extend(
            state_components
                .iter()
                .chain(measurement_components)
                // A component without samples has no interval either.
                .filter(|c| !c.interval.lower.is_nan())
                .map(|c| c.verdict),
        );
        // A mean test without a statistic (no sign in the records, no variance) is no
        // test; it does not make the gate inconclusive.
        verdicts.extend(
            state_components
                .iter()
                .chain(measurement_components)
                .filter(|c| c.mean_z.is_finite())
                .map(|c| c.mean_verdict),
        );
        verdicts.extend(whiteness_tests.iter().map(|w| w.verdict));
    }
    verdicts
}

/// Whether a bias explains every component that fails: a bias raises the second moments
/// (E[y²] = 1 + b²), the time averages and the lagged products of the whiteness test with
/// it, so when it explains every component off its target, it is the verdict.
fn bias_explains_all(
    state_components: &[ComponentStat],
    measurement_components: &[ComponentStat],
) -> bool {
    let comps = || {
        state_components
            .iter()
            .chain(measurement_components)
            .filter(|c| c.samples > 0.0)
    };
    comps().any(|c| c.bias_explains())
        && comps().all(|c| {
            c.bias_explains()
                || !matches!(c.verdict, Verdict::Overconfident | Verdict::Underconfident)
        })
}

/// Read `report`'s components and whiteness for which of Q and R is off (see the module
/// documentation for the reasoning).
pub fn diagnose(report: &ConsistencyReport) -> Diagnosis {
    diagnose_components(&Evidence {
        states: &report.state_components,
        measurements: &report.measurement_components,
        whiteness: &report.whiteness_tests,
    })
}

/// The gate's tests of `report` as standard normal deviates under consistency, one per
/// test the gate applies (for the mean gate: the time averages only): a time average or
/// component `v` with target `d` and interval `[a, b]` at the test level ℓ gives
/// `z_{1−ℓ/2} (v − d)/(b − d)` above the target and `z_{1−ℓ/2} (v − d)/(d − a)` below it, so
/// that the interval's ends are ±`z_{1−ℓ/2}`; each whiteness lag gives `√pairs · ρ_l`. A
/// filter passes the gate with probability about 1 − α when every entry is near 0, and the
/// sum of squares is what a search must drive down to land where the gate passes.
pub fn gate_deviates(report: &ConsistencyReport) -> Vec<f64> {
    let z = normal_two_sided_quantile(report.statistic_alpha);
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
    if report.gate == GateMode::Full {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::MIN_BATCHES;

    fn names(prefix: &str, n: usize) -> Vec<String> {
        (0..n).map(|j| format!("{prefix}{j}")).collect()
    }

    /// Sums with three state and three measurement components: states 0 and 1 have
    /// second-moment samples and state 0 alone signed ones (its mean is tested); measurements
    /// 0 and 1 have samples; only measurement 0 has innovation pairs (two lags). Nothing
    /// else is filled: the counts and levels depend on which components have data.
    fn sums() -> Accumulator {
        let mut acc = Accumulator::new(5, 3, 3, 2);
        acc.state_comp_samples = vec![10.0, 10.0, 0.0];
        acc.state_mean_samples = vec![10.0, 0.0, 0.0];
        acc.meas_comp_samples = vec![10.0, 10.0, 0.0];
        for lag in 0..2 {
            acc.white_pairs[lag * 3] = 8.0;
        }
        acc
    }

    fn report(acc: &Accumulator, mode: GateMode, use_nees: bool) -> ConsistencyReport {
        let gate = GateSpec {
            alpha: 0.05,
            mode,
            use_nees,
        };
        let (n_x, n_z) = (acc.state_comp_total.len(), acc.meas_comp_total.len());
        ConsistencyReport::from_accumulator(acc, &gate, &names("x", n_x), &names("z", n_z))
    }

    #[test]
    fn gate_test_count_and_sidak_levels_with_one_slot_for_the_zero_mean_tests() {
        // Full gate with truth: ANIS, ANEES, 2 state second moments, 1 state mean, 2
        // measurement second moments and 2 means, 1 whiteness test: 10 tests, of which the
        // 3 means share one Šidák slot: k = 8, level 1 − 0.95^{1/8}, each mean a third of it.
        // Without truth: ANIS, 2 + 2 measurement tests, 1 whiteness: 6, k = 5, means halves.
        // Mean gate: the time averages alone (2 with truth, 1 without), means at α. Levels
        // computed independently (Python, 1 − 0.95**(1/k)); tolerance 1e-12 relative.
        let cases = [
            (GateMode::Full, true, 10, 0.006391150954545011, 3.0),
            (GateMode::Full, false, 6, 0.010206218313011495, 2.0),
            (GateMode::Mean, true, 2, 0.025320565519103666, f64::NAN),
            (GateMode::Mean, false, 1, 0.05, f64::NAN),
        ];
        for (mode, use_nees, tests, level, means) in cases {
            let r = report(&sums(), mode, use_nees);
            let what = format!("{mode:?} gate, truth {use_nees}");
            assert_eq!(r.tests, tests, "{what}: test count");
            assert!(
                (r.statistic_alpha - level).abs() <= 1e-12 * level,
                "{what}: Šidák level {} vs {level}",
                r.statistic_alpha
            );
            // In the mean gate the zero-mean tests are diagnostics at α.
            let mean_level = if means.is_nan() { 0.05 } else { level / means };
            assert!(
                (r.mean_alpha - mean_level).abs() <= 1e-12 * mean_level,
                "{what}: zero-mean level {} vs {mean_level}",
                r.mean_alpha
            );
            assert_eq!(r.nees.is_some(), use_nees, "{what}: NEES summary");
            assert_eq!(r.state_components.len(), if use_nees { 3 } else { 0 });
            assert_eq!(r.measurement_components.len(), 3);
            assert_eq!(
                r.whiteness_tests.len(),
                1,
                "{what}: whiteness tested where there are pairs"
            );
        }
    }

    #[test]
    fn a_full_gate_without_zero_mean_tests_gives_every_test_an_equal_share() {
        // No signed samples and no measurement samples: ANIS, ANEES, 2 state second moments
        // and 1 whiteness test, k = 5 with no slot for means (there are none).
        let mut acc = sums();
        acc.state_mean_samples = vec![0.0; 3];
        acc.meas_comp_samples = vec![0.0; 3];
        let r = report(&acc, GateMode::Full, true);
        assert_eq!(r.tests, 5);
        let level = 0.010206218313011495;
        assert!((r.statistic_alpha - level).abs() <= 1e-12 * level);
        assert!(
            (r.mean_alpha - level).abs() <= 1e-12 * level,
            "no mean tests: their level is the statistics' level"
        );
    }

    /// Two-sided 95% points of χ² from a printed table (NIST/SEMATECH e-Handbook,
    /// §1.3.6.7.4), to its three decimals: `(dof, χ²₀.₀₂₅, χ²₀.₉₇₅)`.
    const CHI2_TABLE: [(f64, f64, f64); 3] = [
        (1.0, 0.000982, 5.024),
        (50.0, 32.357, 71.420),
        (100.0, 74.222, 129.561),
    ];
    /// Half a unit in the table's last place (the quantiles are divided by the count
    /// before the comparison, which scales this too).
    const TABLE_TOL: f64 = 5e-4;

    fn table(dof: f64) -> (f64, f64) {
        let &(_, lo, hi) = CHI2_TABLE.iter().find(|t| t.0 == dof).expect("tabulated");
        (lo, hi)
    }

    fn assert_interval(iv: &Interval, dof: f64, count: f64, what: &str) {
        let (lo, hi) = table(dof);
        let tol = TABLE_TOL / count;
        assert!(
            (iv.lower - lo / count).abs() <= tol && (iv.upper - hi / count).abs() <= tol,
            "{what}: interval [{}, {}] vs the table's [{lo}, {hi}] / {count}",
            iv.lower,
            iv.upper
        );
    }

    #[test]
    fn nis_summary_steps_time_average_and_interval_against_the_table() {
        // Mean gate without truth: one test, at α = 0.05. Three steps with data (a step
        // without a measurement between): 100 runs at n_z = 1 with average 0.9 (inside
        // [74.222, 129.561]/100), 100 at n_z = 1 with 1.5 (above), then 50 runs at n_z = 1
        // with average 0.8: per step [32.357, 71.420]/50, inside. Time average 280/250 =
        // 1.12, inside the 250-dof interval (about [0.83, 1.18]; not tabulated).
        let mut acc = Accumulator::new(4, 0, 1, 0);
        acc.runs = 100;
        (acc.nis_sum, acc.nis_dof, acc.nis_count) = (
            vec![90.0, 150.0, 0.0, 40.0],
            vec![100.0, 100.0, 0.0, 50.0],
            vec![100.0, 100.0, 0.0, 50.0],
        );
        let r = report(&acc, GateMode::Mean, false);
        let s = &r.nis;
        assert_eq!(s.per_step, vec![Some(0.9), Some(1.5), None, Some(0.8)]);
        assert_eq!(
            s.per_step_target,
            vec![Some(1.0), Some(1.0), None, Some(1.0)]
        );
        assert_eq!(s.steps_with_data, 3, "steps with data");
        let bounds = |k: usize| Interval {
            lower: s.per_step_lower[k].unwrap(),
            upper: s.per_step_upper[k].unwrap(),
        };
        assert_interval(&bounds(0), 100.0, 100.0, "step 1");
        assert_interval(&bounds(1), 100.0, 100.0, "step 2");
        assert_interval(&bounds(3), 50.0, 50.0, "step 4");
        assert_eq!((s.per_step_lower[2], s.per_step_upper[2]), (None, None));
        assert!(
            (s.fraction_in_bounds - 2.0 / 3.0).abs() < 1e-15,
            "steps inside: 2 of 3, {}",
            s.fraction_in_bounds
        );
        assert!((s.time_average - 1.12).abs() < 1e-12, "{}", s.time_average);
        assert_eq!((s.target, s.naive_dof), (1.0, 250.0));
        assert!(s.per_step_has_power && s.has_power);
        assert_eq!(
            s.verdict,
            Verdict::Consistent,
            "1.12 inside the 250-dof interval"
        );
        assert_eq!(r.verdict, Verdict::Consistent);
    }

    #[test]
    fn a_single_scalar_innovation_is_tested_against_chi2_of_one_degree_of_freedom() {
        // One run, one step, one scalar measurement: the NIS and the measurement component
        // are χ²(1) (variance 2), interval [0.000982, 5.024] at α = 0.05; one degree of
        // freedom has no power, so the verdicts are inconclusive.
        let mut acc = Accumulator::new(1, 0, 1, 0);
        acc.runs = 1;
        (acc.nis_sum, acc.nis_dof, acc.nis_count) = (vec![2.0], vec![1.0], vec![1.0]);
        (acc.meas_comp_total, acc.meas_comp_samples) = (vec![2.0], vec![1.0]);
        let r = report(&acc, GateMode::Mean, false);
        assert_interval(&r.nis.interval, 1.0, 1.0, "NIS time average");
        assert_interval(&r.nis.naive_interval, 1.0, 1.0, "NIS naive interval");
        assert!(
            (r.nis.effective_dof - 1.0).abs() < 1e-12,
            "{}",
            r.nis.effective_dof
        );
        let c = &r.measurement_components[0];
        assert_interval(&c.interval, 1.0, 1.0, "measurement component");
        assert_eq!(r.nis.verdict, Verdict::Inconclusive, "no power at 1 dof");
    }

    /// Sums of 100 samples per component over 4 runs with the filters' predicted variances
    /// for the squares (white: 2 per sample) and per-run first-moment sums spread with
    /// sample variance 25 about their mean (so the zero-mean tests' variance is
    /// 4 · 25 = 100): state 0 consistent, state 1 twice its variance with a mean of 0.5 σ,
    /// measurement 0 at 0.6 with a mean of −0.3 σ, measurement 1 at 1.49 with a mean of
    /// 0.7 σ (1.49 − 0.7² = 1: a bias alone).
    fn component_sums() -> Accumulator {
        let mut acc = Accumulator::new(1, 2, 2, 0);
        acc.runs = 4;
        acc.comp_null_var_runs = 4;
        acc.meas_comp_runs = vec![4, 4];
        // Σ r² = (N − 1) s² + N m², m the per-run mean: 3 · 25 + 4 m².
        let run_sq = |total: f64| 75.0 + 4.0 * (total / 4.0).powi(2);
        acc.state_mean_run_sq = vec![run_sq(10.0), run_sq(50.0)];
        acc.meas_mean_run_sq = vec![run_sq(-30.0), run_sq(70.0)];
        acc.state_comp_total = vec![100.0, 200.0];
        acc.state_comp_samples = vec![100.0, 100.0];
        acc.state_comp_null_var = vec![200.0, 200.0];
        acc.state_mean_total = vec![10.0, 50.0];
        acc.state_mean_samples = vec![100.0, 100.0];
        acc.state_mean_null_var = vec![100.0, 100.0];
        acc.meas_comp_total = vec![60.0, 149.0];
        acc.meas_comp_samples = vec![100.0, 100.0];
        acc.meas_mean_total = vec![-30.0, 70.0];
        acc
    }

    #[test]
    fn component_values_intervals_and_zero_mean_tests_by_hand() {
        // Mean gate: the components are diagnostics at α = 0.05, so each interval is the
        // table's [74.222, 129.561]/100, and each zero-mean test is two-sided Student t on
        // 3 degrees of freedom (4 runs) at t = 3.182 (tables) on z = T / √(N s²) = T / 10:
        // state 0: z = 1; state 1: 5; measurement 0: −3 (inside: 4 runs cannot tell);
        // measurement 1: 7. Tolerance 1e-12.
        let r = report(&component_sums(), GateMode::Mean, true);
        let want = [
            (
                "state 0",
                1.0,
                Verdict::Consistent,
                0.1,
                1.0,
                Verdict::Consistent,
                false,
            ),
            (
                "state 1",
                2.0,
                Verdict::Overconfident,
                0.5,
                5.0,
                Verdict::Biased,
                false,
            ),
            (
                "measurement 0",
                0.6,
                Verdict::Underconfident,
                -0.3,
                -3.0,
                Verdict::Consistent,
                false,
            ),
            (
                "measurement 1",
                1.49,
                Verdict::Overconfident,
                0.7,
                7.0,
                Verdict::Biased,
                true,
            ),
        ];
        let comps: Vec<&ComponentStat> = r
            .state_components
            .iter()
            .chain(&r.measurement_components)
            .collect();
        assert_eq!(comps.len(), 4);
        for (c, (what, value, verdict, mean, z, mean_verdict, bias)) in comps.iter().zip(want) {
            assert!((c.value - value).abs() < 1e-12, "{what}: value {}", c.value);
            assert_interval(&c.interval, 100.0, 100.0, what);
            assert_eq!(c.verdict, verdict, "{what}: second moment");
            assert!((c.mean - mean).abs() < 1e-12, "{what}: mean {}", c.mean);
            assert!(
                (c.mean_z - z).abs() < 1e-12,
                "{what}: zero-mean z {} vs {z}",
                c.mean_z
            );
            assert_eq!(c.mean_verdict, mean_verdict, "{what}: zero-mean verdict");
            assert_eq!(c.bias_explains(), bias, "{what}: the bias explains it");
        }
        // The worst first by |ln value|: state 1 (ln 2), measurement 0 (ln 0.6), then
        // measurement 1 (ln 1.49); state 0 (ln 1 = 0) last.
        let worst: Vec<&str> = r
            .worst_components(3)
            .iter()
            .map(|c| c.name.as_str())
            .collect();
        assert_eq!(worst, vec!["x1", "z0", "z1"], "worst components");
    }

    /// Sums at their targets: 50 runs of 4 steps, 2 states and 2 measurements, NEES and NIS
    /// averages 2, each component's squares averaging 1 with zero mean, white innovations
    /// at lag 1, and the filters' predicted variances of white terms.
    fn consistent() -> Accumulator {
        let (runs, steps) = (50.0, 4);
        let mut acc = Accumulator::new(steps, 2, 2, 1);
        acc.runs = 50;
        for k in 0..steps {
            acc.nees_sum[k] = 2.0 * runs;
            acc.nees_dof[k] = 2.0 * runs;
            acc.nees_count[k] = runs;
            acc.nis_sum[k] = 2.0 * runs;
            acc.nis_dof[k] = 2.0 * runs;
            acc.nis_count[k] = runs;
        }
        (acc.null_var_runs, acc.nees_null_var) = (50, 50.0 * 2.0 * 2.0 * 4.0);
        acc.comp_null_var_runs = 50;
        let n = runs * steps as f64;
        acc.state_comp_total = vec![n; 2];
        acc.state_comp_samples = vec![n; 2];
        acc.state_comp_null_var = vec![2.0 * n; 2];
        acc.state_mean_samples = vec![n; 2];
        acc.state_mean_null_var = vec![n; 2];
        acc.meas_comp_total = vec![n; 2];
        acc.meas_comp_samples = vec![n; 2];
        // Each run's first-moment sum over 4 white steps has variance 4, about a mean of 0.
        acc.state_mean_run_sq = vec![runs * 4.0; 2];
        acc.meas_mean_run_sq = vec![runs * 4.0; 2];
        acc.meas_comp_runs = vec![50; 2];
        for j in 0..2 {
            acc.white_pairs[j] = runs * 3.0;
            acc.white_a2[j] = runs * 3.0;
            acc.white_b2[j] = runs * 3.0;
        }
        acc
    }

    #[test]
    fn the_gate_combines_every_test_and_names_a_bias_that_explains_every_failure() {
        let full = |acc: &Accumulator| report(acc, GateMode::Full, true);
        let r = full(&consistent());
        assert_eq!(
            r.verdict,
            Verdict::Consistent,
            "at the targets: {:?}",
            r.verdict
        );
        assert!(r.diagnosis.findings.is_empty() && r.diagnosis.suspect.is_none());

        // A bias on measurement 0 (mean 0.7 σ, squares 1.49 = 1 + 0.7²): its second moment
        // fails because of the bias alone, so the verdict is the bias.
        let mut biased = consistent();
        biased.meas_mean_total[0] = 0.7 * 200.0;
        // The per-run sums about their new mean 2.8: 49 · 4 + 50 · 2.8².
        biased.meas_mean_run_sq[0] = 49.0 * 4.0 + 50.0 * 2.8 * 2.8;
        biased.meas_comp_total[0] = 1.49 * 200.0;
        let r = full(&biased);
        assert_eq!(
            r.measurement_components[0].verdict,
            Verdict::Overconfident,
            "the second moment fails"
        );
        assert_eq!(
            r.verdict,
            Verdict::Biased,
            "a bias that explains every failure"
        );
        assert!(
            !r.diagnosis.findings.is_empty(),
            "a failing gate is diagnosed"
        );

        // And state 1 twice its variance without a bias: the bias no longer explains every
        // failure, so the second moments decide.
        biased.state_comp_total[1] = 2.0 * 200.0;
        let r = full(&biased);
        assert_eq!(r.verdict, Verdict::Overconfident, "{:?}", r.verdict);

        // A component without samples is no test: it does not make the gate inconclusive.
        let mut acc = Accumulator::new(4, 3, 2, 1);
        let c = consistent();
        acc.merge(&Accumulator {
            state_comp_total: vec![c.state_comp_total[0], c.state_comp_total[1], 0.0],
            state_comp_samples: vec![c.state_comp_samples[0], c.state_comp_samples[1], 0.0],
            state_comp_run_sum: vec![0.0; 3],
            state_comp_run_sq: vec![0.0; 3],
            state_comp_null_var: vec![c.state_comp_null_var[0], c.state_comp_null_var[1], 0.0],
            state_mean_total: vec![0.0; 3],
            state_mean_samples: vec![c.state_mean_samples[0], c.state_mean_samples[1], 0.0],
            state_mean_run_sq: vec![0.0; 3],
            state_mean_null_var: vec![c.state_mean_null_var[0], c.state_mean_null_var[1], 0.0],
            ..c
        });
        let r = report(&acc, GateMode::Full, true);
        assert_eq!(
            r.tests,
            2 + 2 + 2 + 4 + 2,
            "the empty component brings no test"
        );
        assert_eq!(r.state_components[2].verdict, Verdict::Inconclusive);
        assert_eq!(r.verdict, Verdict::Consistent, "{:?}", r.verdict);

        // Runs that stopped early decide the verdict, and leave nothing to diagnose.
        let mut stopped = consistent();
        stopped.state_comp_total[1] = 2.0 * 200.0;
        stopped.record_divergence(3, 2, "P lost definiteness".into());
        let r = full(&stopped);
        assert_eq!(r.verdict, Verdict::Diverged);
        assert!(
            r.diagnosis.findings.is_empty(),
            "no diagnosis on runs that stopped: {:?}",
            r.diagnosis.findings
        );
    }

    /// One run of `steps` steps of a 2-state filter without an error map: NEES per step
    /// `scale · (2 + 0.8 sin 0.7k)`, each state's squares summing to the same, no
    /// innovations.
    fn one_recording(steps: usize, scale: f64) -> Accumulator {
        let mut acc = Accumulator::new(steps, 2, 1, 1);
        acc.runs = 1;
        acc.error_map_missing = 1;
        let mut total = 0.0;
        for k in 0..steps {
            let nees = scale * (2.0 + 0.8 * (0.7 * k as f64).sin());
            acc.nees_sum[k] = nees;
            acc.nees_dof[k] = 2.0;
            acc.nees_count[k] = 1.0;
            total += nees;
        }
        acc.add_run_nees_total(total);
        acc.state_comp_total = vec![total / 2.0; 2];
        acc.state_comp_samples = vec![steps as f64; 2];
        acc.state_comp_run_sum = vec![total / 2.0 / steps as f64; 2];
        acc.state_comp_run_sq = vec![(total / 2.0 / steps as f64).powi(2); 2];
        acc
    }

    #[test]
    fn one_recording_is_judged_by_batch_means_and_untested_parts_leave_the_gate_alone() {
        // 200 steps whose NEES swings ±0.8 about 2 with a period of 9 steps: batch means
        // gives an interval about 2 (the blocks average the swing out), the two state
        // components have no spread to be tested by and ANIS has no data, so neither makes
        // the gate inconclusive: consistent. Twice the NEES is overconfident.
        let r = report(&one_recording(200, 1.0), GateMode::Full, true);
        let nees = r.nees.as_ref().unwrap();
        let blocks = nees.batch_spread_batches.expect("batch means");
        assert!((MIN_BATCHES..=32).contains(&blocks), "{blocks}");
        assert_eq!(nees.run_spread_runs, None);
        assert!(
            nees.interval.contains(2.0) && nees.interval.upper < 2.5,
            "{:?}",
            nees.interval
        );
        assert_eq!(nees.verdict, Verdict::Consistent);
        assert_eq!(r.nis.steps_with_data, 0);
        assert!(r.state_components.iter().all(|c| c.interval.lower.is_nan()));
        assert_eq!(r.verdict, Verdict::Consistent, "{:?}", r.verdict);
        let r = report(&one_recording(200, 2.0), GateMode::Full, true);
        assert_eq!(r.verdict, Verdict::Overconfident);
        // 39 steps are too few for eight blocks of five: no interval, no verdict.
        let r = report(&one_recording(39, 1.0), GateMode::Full, true);
        let nees = r.nees.as_ref().unwrap();
        assert!(nees.interval.lower.is_nan() && nees.batch_spread_batches.is_none());
        assert_eq!(r.verdict, Verdict::Inconclusive);
        // Steps without a NEES (a recording whose reference ends early) are not part of
        // the series.
        let mut longer = one_recording(220, 1.0);
        for k in 200..220 {
            (longer.nees_sum[k], longer.nees_dof[k], longer.nees_count[k]) = (0.0, 0.0, 0.0);
        }
        assert_eq!(
            longer.nees_sum_variance(),
            one_recording(200, 1.0).nees_sum_variance()
        );
        // Nothing with data at all (no NEES judged, no innovations): inconclusive, never a
        // pass.
        let r = report(&one_recording(200, 1.0), GateMode::Full, false);
        assert_eq!(r.verdict, Verdict::Inconclusive);
    }
}
