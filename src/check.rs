//! Judging a filter at θ: an experiment's Monte Carlo sums put through the gate. `autotune
//! check`, the tuner's refinement and confirmation, and the explanations all judge through
//! [`judge`], so a filter passes the same tests wherever it is judged. One seed is one draw
//! of a random test that a consistent filter fails with probability α; [`check_seeds`]
//! repeats the check on K independent seeds and judges the count of failures.

use crate::experiment::{Experiment, ExperimentError, RunOptions};
use crate::montecarlo::McConfig;
use statrs::distribution::{Binomial, DiscreteCDF};

use crate::rng::seed_at;
use crate::stats::{Accumulator, ConsistencyReport};

/// What the filter is judged by: whether the truth it runs against is trusted, so that the
/// estimation errors (NEES) count beside the innovations (NIS).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Truth {
    /// The truth is known (a simulation): NEES and NIS both judged.
    Known,
    /// No trusted truth (field data, or states the filter does not share with the truth):
    /// NIS alone.
    Unknown,
}

impl Truth {
    /// [`Truth::Known`] when `use_nees`: the gate's own flag ([`crate::stats::GateSpec`]).
    pub(crate) fn from_use_nees(use_nees: bool) -> Truth {
        if use_nees {
            Truth::Known
        } else {
            Truth::Unknown
        }
    }

    /// Whether the NEES is judged.
    pub fn uses_nees(self) -> bool {
        self == Truth::Known
    }
}

/// The gate applied to `sums`, the Monte Carlo sums of `experiment`'s filter under `mc`:
/// the full consistency report (time averages, components, whiteness, zero-mean tests and
/// the verdict at `mc`'s α), by NEES and NIS or by NIS alone as `truth` says.
pub fn judge(
    experiment: &dyn Experiment,
    sums: &Accumulator,
    mc: &McConfig,
    truth: Truth,
) -> ConsistencyReport {
    ConsistencyReport::from_accumulator(
        sums,
        &mc.gate_spec(truth.uses_nees()),
        experiment.state_names(),
        experiment.measurement_names(),
    )
}

/// Check `experiment`'s filter at parameter values `theta` under `mc`: its Monte Carlo run
/// and [`judge`]d. Fails only when the experiment cannot run (see
/// [`Experiment::monte_carlo_with`]).
pub fn check(
    experiment: &dyn Experiment,
    theta: &[f64],
    mc: &McConfig,
    truth: Truth,
) -> Result<ConsistencyReport, ExperimentError> {
    check_with(experiment, theta, mc, RunOptions::default(), truth)
}

/// [`check`] on a chosen engine path, with progress.
pub fn check_with(
    experiment: &dyn Experiment,
    theta: &[f64],
    mc: &McConfig,
    options: RunOptions<'_>,
    truth: Truth,
) -> Result<ConsistencyReport, ExperimentError> {
    let sums = experiment.monte_carlo_with(theta, mc, options)?;
    Ok(judge(experiment, &sums, mc, truth))
}

/// [`check`] on `seeds` independent seeds: `mc`'s own seed first (so the first check is
/// [`check`]'s), then the seeds after it, as the tuner's confirmation draws them. Where a
/// single check and a tune disagree, this says whether the disagreement is one unlucky
/// seed: a consistent filter fails each check with probability at most α. The band needs
/// a few seeds to decide anything: with one, a failure is inside it (Binomial(1, 0.95)
/// gives 0 passes 5% of the time); of 20, as the confirmation uses, a consistent filter
/// passes at least 16 with 99% probability.
pub fn check_seeds(
    experiment: &dyn Experiment,
    theta: &[f64],
    mc: &McConfig,
    truth: Truth,
    seeds: usize,
) -> Result<SeedChecks, ExperimentError> {
    let checks = (0..seeds)
        .map(|k| {
            let seed = seed_at(mc.seed(), k);
            let report = check(experiment, theta, &mc.with_seed(seed), truth)?;
            Ok(SeedCheck { seed, report })
        })
        .collect::<Result<Vec<_>, ExperimentError>>()?;
    Ok(SeedChecks {
        checks,
        alpha: mc.alpha(),
    })
}

/// One seed's check of [`check_seeds`].
#[derive(Debug, Clone)]
pub struct SeedCheck {
    /// The Monte Carlo seed.
    pub seed: u64,
    /// The check on that seed.
    pub report: ConsistencyReport,
}

/// The checks of one filter on K independent seeds ([`check_seeds`]), judged together as
/// the tuner's confirmation judges its seeds: each check of a consistent filter passes with
/// probability at least 1 − α, so its pass count is at least Binomial(K, 1 − α) in
/// distribution, and a count below that distribution's 1% quantile says the filter is not
/// consistent.
#[derive(Debug, Clone)]
pub struct SeedChecks {
    /// The checks, in seed order.
    pub checks: Vec<SeedCheck>,
    /// The significance level α of every check and of the count.
    pub alpha: f64,
}

impl SeedChecks {
    /// How many seeds' checks passed.
    pub fn passed(&self) -> usize {
        self.checks
            .iter()
            .filter(|c| c.report.verdict.passes())
            .count()
    }

    /// The lowest pass count of these K seeds inside the band of a consistent filter
    /// ([`band_low`]), the band the tuner's confirmation judges by.
    pub fn band_low(&self) -> usize {
        band_low(self.checks.len(), self.alpha)
    }

    /// Whether as many seeds passed as a consistent filter's would: at least
    /// [`SeedChecks::band_low`].
    pub fn passes(&self) -> bool {
        self.passed() >= self.band_low()
    }
}

/// The confirmation's band: a consistent filter's pass count falls below it with
/// probability at most this.
const BAND: f64 = 0.01;

/// The lowest pass count of K seeds inside the band of a filter that passes each with
/// probability `1 − alpha`.
pub fn band_low(seeds: usize, alpha: f64) -> usize {
    match Binomial::new(1.0 - alpha, seeds as u64) {
        // The smallest c with P(X ≤ c) > BAND; a count below it is improbable.
        Ok(b) => (0..=seeds)
            .find(|&c| b.cdf(c as u64) > BAND)
            .unwrap_or(seeds),
        Err(_) => seeds,
    }
}

/// Told how a check's Monte Carlo goes: the command line draws a progress bar.
pub trait CheckProgress: Sync {
    /// The run is about to start: `runs` × `steps`, on the linear fast path or not (which
    /// steps about 100 times faster).
    fn start(&self, _runs: usize, _steps: usize, _fast_path: bool) {}
    /// `done` runs have finished.
    fn runs_done(&self, _done: usize) {}
    /// The run is over (finished or failed).
    fn finish(&self) {}
}

/// No progress reports.
impl CheckProgress for () {}

/// The Monte Carlo sums of `experiment`'s filter at `theta` on the `engine` path.
pub fn accumulate(
    experiment: &dyn Experiment,
    theta: &[f64],
    mc: &McConfig,
    engine: crate::montecarlo::Engine,
) -> Result<Accumulator, ExperimentError> {
    experiment.monte_carlo_with(
        theta,
        mc,
        RunOptions {
            engine,
            progress: None,
            share: None,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiment::LinearExperiment;

    /// cv1d (q = 0.5, r = 1) on a short test: 50 runs × 40 steps.
    fn cv1d() -> LinearExperiment {
        crate::experiment::cv1d_for_tests()
            .montecarlo(McConfig::new(50, 40).unwrap().with_seed(3))
            .build()
            .unwrap()
    }

    #[test]
    fn seeds_are_checked_from_the_single_checks_seed_on() {
        let model = cv1d();
        let mc = *model.mc();
        let checks = check_seeds(&model, &[0.5, 1.0], &mc, Truth::Known, 12).unwrap();
        assert_eq!(checks.checks.len(), 12);
        let seeds: Vec<u64> = checks.checks.iter().map(|c| c.seed).collect();
        assert_eq!(seeds, (3..15).collect::<Vec<u64>>());
        // The first is the single check, to the bit; each later one its own seed's.
        let single = check(&model, &[0.5, 1.0], &mc, Truth::Known).unwrap();
        let anees = |r: &ConsistencyReport| r.nees.as_ref().unwrap().time_average;
        assert_eq!(anees(&checks.checks[0].report), anees(&single));
        let later = check(&model, &[0.5, 1.0], &mc.with_seed(7), Truth::Known).unwrap();
        assert_eq!(anees(&checks.checks[4].report), anees(&later));
        assert_ne!(anees(&checks.checks[1].report), anees(&single));
        // Bin(12, 0.95): P(X ≤ 8) = 0.0022, P(X ≤ 9) = 0.0196, so 9 passes are the band.
        assert_eq!(checks.band_low(), 9);
        assert!(checks.passes(), "{} of 12 passed", checks.passed());
        assert_eq!(checks.alpha, mc.alpha());
    }

    #[test]
    fn a_filter_ten_times_off_fails_on_every_seed_and_nis_alone_sees_it_too() {
        let model = cv1d();
        for truth in [Truth::Known, Truth::Unknown] {
            let checks = check_seeds(&model, &[5.0, 10.0], model.mc(), truth, 4).unwrap();
            assert_eq!(checks.passed(), 0);
            assert!(!checks.passes());
            let nees = checks.checks[0].report.nees.is_some();
            assert_eq!(nees, truth.uses_nees());
        }
        let none = check_seeds(&model, &[0.5, 1.0], model.mc(), Truth::Known, 0).unwrap();
        assert!(none.checks.is_empty() && none.passes());
    }

    #[test]
    fn band_of_twenty_seeds_at_five_percent() {
        // Bin(20, 0.95): P(X ≤ 15) = 0.0026, P(X ≤ 16) = 0.0159, so 16 is the lowest count
        // inside a 99% band.
        assert_eq!(band_low(20, 0.05), 16);
        // Bin(100, 0.95): P(X ≤ 88) = 0.0043, P(X ≤ 89) = 0.0115 (computed with exact
        // binomial sums in Python).
        assert_eq!(band_low(100, 0.05), 89);
    }
}
