//! The settings of a Monte Carlo consistency test, checked where they are set.

use std::fmt::Display;

use crate::input::{SettingError, at_least as count, at_most};
use crate::stats::{GateMode, GateSpec};

/// Largest number of steps per run: per-step sums and the linear engine's per-step gains
/// take memory proportional to T (about 0.5 kB per step for four states).
pub const MAX_STEPS: usize = 1_000_000;

/// Largest number of runs N, 10¹². Memory does not grow with N (the engines stream the runs
/// in chunks), so the bound is about arithmetic, not memory: N·T stays below 2⁶³ (with T ≤
/// [`MAX_STEPS`], N·T ≤ 10¹⁸), the tuner's default 4 N search runs fit in a `usize`, and the
/// per-step counts of runs, summed as `f64`, stay exact integers (below 2⁵³ ≈ 9·10¹⁵ for
/// up to 9 000 measurement components). At 10⁸ filter steps a second, 10¹² runs of one step
/// take three hours and of a thousand steps four months, so no test anyone waits for is
/// refused.
pub const MAX_RUNS: usize = 1_000_000_000_000;

/// Default significance level α of the two-sided tests.
pub const DEFAULT_ALPHA: f64 = 0.05;

/// Default largest innovation-autocorrelation lag (capped at T − 1).
pub const DEFAULT_LAGS: usize = 5;

/// A Monte Carlo consistency test: N runs of T steps from a base seed, tested at
/// significance α by a gate of the chosen kind, with innovation autocorrelations up to a
/// lag. Every value is checked by its setter, so a `McConfig` is always valid:
/// 1 ≤ N ≤ `MAX_RUNS`, 1 ≤ T ≤ `MAX_STEPS`,
/// 0 < α < 1, lags < T.
///
/// ```
/// use autotune::McConfig;
/// let mc = McConfig::new(200, 100)?.with_seed(7).with_alpha(0.01)?;
/// assert_eq!((mc.runs(), mc.steps(), mc.lags()), (200, 100, 5));
/// assert!(McConfig::new(0, 100).is_err());
/// assert!(mc.with_lags(100).is_err());
/// # Ok::<(), autotune::SettingError>(())
/// ```
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct McConfig {
    runs: usize,
    steps: usize,
    seed: u64,
    alpha: f64,
    lags: usize,
    gate: GateMode,
}

impl McConfig {
    /// `runs` × `steps` with seed 0, α = `DEFAULT_ALPHA` and lags up to
    /// `DEFAULT_LAGS` (at most T − 1).
    pub fn new<R, S>(runs: R, steps: S) -> Result<McConfig, SettingError>
    where
        R: TryInto<usize> + Display + Copy,
        S: TryInto<usize> + Display + Copy,
    {
        let mc = McConfig {
            runs: 1,
            steps: 1,
            seed: 0,
            alpha: DEFAULT_ALPHA,
            lags: DEFAULT_LAGS,
            gate: GateMode::Full,
        };
        mc.with_runs(runs)?.with_steps(steps)
    }

    /// Number of runs N, in 1..=`MAX_RUNS`.
    pub fn with_runs<R: TryInto<usize> + Display + Copy>(
        mut self,
        runs: R,
    ) -> Result<McConfig, SettingError> {
        self.runs = at_most("runs", count("runs", runs, 1)?, MAX_RUNS)?;
        Ok(self)
    }

    /// Steps per run T, in 1..=`MAX_STEPS`; the lags are capped at T − 1.
    pub fn with_steps<S: TryInto<usize> + Display + Copy>(
        mut self,
        steps: S,
    ) -> Result<McConfig, SettingError> {
        let t = steps
            .try_into()
            .ok()
            .filter(|t| (1..=MAX_STEPS).contains(t))
            .ok_or_else(|| {
                SettingError::new("steps", format!("{steps} must be in 1..={MAX_STEPS}"))
            })?;
        self.steps = t;
        self.lags = self.lags.min(t - 1);
        Ok(self)
    }

    /// Base seed: run i draws from the stream derived from (seed, i).
    pub fn with_seed(mut self, seed: u64) -> McConfig {
        self.seed = seed;
        self
    }

    /// Significance level α of the two-sided tests, in (0, 1).
    pub fn with_alpha(mut self, alpha: f64) -> Result<McConfig, SettingError> {
        if !(alpha > 0.0 && alpha < 1.0) {
            return Err(SettingError::new(
                "alpha",
                format!("{alpha} must be in (0, 1)"),
            ));
        }
        self.alpha = alpha;
        Ok(self)
    }

    /// Largest innovation-autocorrelation lag, below T.
    pub fn with_lags<L: TryInto<usize> + Display + Copy>(
        mut self,
        lags: L,
    ) -> Result<McConfig, SettingError> {
        let l = count("lags", lags, 0)?;
        if l >= self.steps {
            return Err(SettingError::new(
                "lags",
                format!("{l} must be below steps ({})", self.steps),
            ));
        }
        self.lags = l;
        Ok(self)
    }

    /// Which tests the consistency gate applies (default: the full gate).
    pub fn with_gate(mut self, gate: GateMode) -> McConfig {
        self.gate = gate;
        self
    }

    /// Which tests the consistency gate applies.
    pub fn gate(&self) -> GateMode {
        self.gate
    }

    /// The gate these settings describe, with or without the ground truth (NEES).
    pub fn gate_spec(&self, use_nees: bool) -> GateSpec {
        GateSpec {
            alpha: self.alpha,
            mode: self.gate,
            use_nees,
        }
    }

    /// Number of runs N.
    pub fn runs(&self) -> usize {
        self.runs
    }

    /// Steps per run T.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Base seed.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Significance level α.
    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// Largest innovation-autocorrelation lag.
    pub fn lags(&self) -> usize {
        self.lags
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn setters_accept_valid_and_refuse_invalid_values() {
        let mc = McConfig::new(10, 20).unwrap();
        assert_eq!(
            (mc.runs(), mc.steps(), mc.lags(), mc.seed()),
            (10, 20, 5, 0)
        );
        assert_eq!(McConfig::new(10, 3).unwrap().lags(), 2);
        assert_eq!(
            McConfig::new(0, 20).unwrap_err(),
            SettingError::new("runs", "0 must be ≥ 1")
        );
        assert_eq!(
            McConfig::new(-3_i64, 20).unwrap_err(),
            SettingError::new("runs", "-3 must be ≥ 1")
        );
        assert_eq!(
            mc.with_steps(0).unwrap_err(),
            SettingError::new("steps", "0 must be in 1..=1000000")
        );
        assert!(mc.with_steps(MAX_STEPS).is_ok() && mc.with_steps(MAX_STEPS + 1).is_err());
        assert_eq!(
            mc.with_steps(2).unwrap().lags(),
            1,
            "lags follow a shorter run"
        );
        for bad in [0.0, 1.0, -0.1, f64::NAN] {
            assert_eq!(mc.with_alpha(bad).unwrap_err().setting, "alpha");
        }
        assert_eq!(mc.with_alpha(0.01).unwrap().alpha(), 0.01);
        assert_eq!(mc.with_lags(19).unwrap().lags(), 19);
        assert_eq!(
            mc.with_lags(20).unwrap_err(),
            SettingError::new("lags", "20 must be below steps (20)")
        );
        assert_eq!(
            mc.with_lags(-1_i64).unwrap_err(),
            SettingError::new("lags", "-1 must be ≥ 0")
        );
        assert_eq!(mc.with_seed(u64::MAX).seed(), u64::MAX);
        assert_eq!(mc.with_runs(MAX_RUNS).unwrap().runs(), MAX_RUNS);
        assert_eq!(
            mc.with_runs(u64::MAX).unwrap_err(),
            SettingError::new("runs", "18446744073709551615 must be ≤ 1000000000000")
        );
        assert_eq!(mc.with_runs(i64::MAX).unwrap_err().setting, "runs");
    }
}
