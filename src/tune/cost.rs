//! The search's cost function: where a candidate lives and what it scores.
//!
//! A candidate is a log-point `y`: the logarithm of each free parameter, inside the box
//! `[ln lower, ln upper]` (variances span decades; a log scale makes "×2" the same step
//! everywhere). Fixed parameters keep their start values. A candidate is scored by the
//! [`Objective`] on the experiment's sums at its parameter values: the exact expected sums
//! or a Monte Carlo run with common random numbers. Nothing here counts evaluations; the
//! [`super::budget::Budget`] wraps this and does.
//!
//! The exact sums are a pure function of the parameter values, and a search asks for the
//! same values again (a simplex vertex outside the box scores its clamped point, a stage
//! re-scores the point it found): measured on one draw of every misfit family, 13% of
//! the evaluations repeated one this cost had made. Those are answered from a memo of the
//! latest exact sums, the same bits; the budget still charges them, so what a search
//! spends and where it stops do not change.

use std::collections::{HashMap, VecDeque};
use std::sync::Mutex;

use super::objective::Objective;
use crate::experiment::{Experiment, ExperimentError};
use crate::montecarlo::McConfig;
use crate::params::Target;
use crate::stats::Accumulator;

/// Weight of the squared distance outside the box in [`Cost::score`]: large enough that a
/// simplex vertex outside never beats one inside.
const BOX_PENALTY: f64 = 1e3;

/// Exact sums the memo keeps, the oldest dropped first: a few megabytes at the sizes the
/// exact path serves (an accumulator holds a few vectors of T steps).
const MEMO_ENTRIES: usize = 512;

/// The latest exact sums by the bits of their parameter values, oldest first in `order`.
#[derive(Default)]
struct Memo {
    sums: HashMap<Vec<u64>, Accumulator>,
    order: VecDeque<Vec<u64>>,
}

impl Memo {
    fn get(&self, key: &[u64]) -> Option<Accumulator> {
        self.sums.get(key).cloned()
    }

    fn insert(&mut self, key: Vec<u64>, acc: &Accumulator) {
        if self.sums.contains_key(&key) {
            return;
        }
        if self.order.len() >= MEMO_ENTRIES
            && let Some(old) = self.order.pop_front()
        {
            self.sums.remove(&old);
        }
        self.order.push_back(key.clone());
        self.sums.insert(key, acc.clone());
    }
}

/// The cost of a candidate, without any accounting.
pub(super) struct Cost<'a> {
    model: &'a dyn Experiment,
    mc: McConfig,
    /// Scored on exact expected sums (no Monte Carlo noise).
    pub(super) exact: bool,
    /// The objective J.
    pub(super) objective: Objective,
    theta0: Vec<f64>,
    free: Vec<usize>,
    /// Lower bounds of the free parameters, log units.
    pub(super) lo: Vec<f64>,
    /// Upper bounds of the free parameters, log units.
    pub(super) hi: Vec<f64>,
    /// Per free parameter, the components it drives (all known, or `None`).
    pub(super) targets: Option<Vec<Target>>,
    /// A score below which the search has found what it was asked for and stops (0: never;
    /// an explanation's trial asks only whether some value fits).
    pub(super) stop_below: f64,
    /// The first failure of the experiment itself (an external worker that broke the
    /// protocol), not of a candidate's filter: once set, the budget refuses every further
    /// evaluation and [`super::tune`] returns it.
    failure: Mutex<Option<ExperimentError>>,
    /// The latest exact sums (see the module's notes).
    memo: Mutex<Memo>,
}

impl<'a> Cost<'a> {
    /// The cost of `model`'s candidates around `start`, holding the parameters marked in
    /// `fixed`, scored by `objective` on exact sums (`exact`) or on Monte Carlo runs `mc`.
    pub(super) fn new(
        model: &'a dyn Experiment,
        mc: McConfig,
        exact: bool,
        objective: Objective,
        start: &[f64],
        fixed: &[bool],
    ) -> Self {
        let params = &model.params().params;
        let free: Vec<usize> = (0..params.len()).filter(|&i| !fixed[i]).collect();
        Cost {
            model,
            mc,
            exact,
            objective,
            theta0: start.to_vec(),
            lo: free.iter().map(|&i| params[i].lower.ln()).collect(),
            hi: free.iter().map(|&i| params[i].upper.ln()).collect(),
            targets: free
                .iter()
                .map(|&i| model.target(i).filter(|t| !t.components.is_empty()))
                .collect(),
            free,
            stop_below: 0.0,
            failure: Mutex::new(None),
            memo: Mutex::new(Memo::default()),
        }
    }

    /// The experiment's sums at `theta` under `mc`; when the experiment itself fails, the
    /// failure is kept and the sums returned mark every run diverged (a candidate scoring
    /// +∞), so that the search stops at its next evaluation instead of panicking mid-way.
    pub(super) fn monte_carlo(&self, theta: &[f64], mc: &McConfig) -> Accumulator {
        match self.model.monte_carlo(theta, mc) {
            Ok(acc) => acc,
            Err(e) => {
                let mut acc = Accumulator::new(
                    mc.steps(),
                    self.model.state_names().len(),
                    self.model.measurement_names().len(),
                    mc.lags(),
                );
                acc.record_divergence(0, 0, e.to_string());
                acc.runs = mc.runs();
                let mut slot = self.failure.lock().unwrap_or_else(|p| p.into_inner());
                slot.get_or_insert(e);
                acc
            }
        }
    }

    /// The experiment's first failure, if it failed.
    pub(super) fn failure(&self) -> Option<ExperimentError> {
        self.failure
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// The Monte Carlo settings candidates are scored on.
    pub(super) fn mc(&self) -> &McConfig {
        &self.mc
    }

    /// The free parameters' indices (problem order): coordinate k of a log-point is
    /// parameter `free()[k]`.
    pub(super) fn free(&self) -> &[usize] {
        &self.free
    }

    /// Moves parameter `param`'s box edges to `lo` and `hi` (log units), if it is free.
    pub(super) fn set_bounds(&mut self, param: usize, lo: f64, hi: f64) {
        if let Some(k) = self.free.iter().position(|&i| i == param) {
            self.lo[k] = lo;
            self.hi[k] = hi;
        }
    }

    /// Number of free parameters.
    pub(super) fn dim(&self) -> usize {
        self.free.len()
    }

    /// The start as a log-point.
    pub(super) fn start(&self) -> Vec<f64> {
        self.free.iter().map(|&i| self.theta0[i].ln()).collect()
    }

    /// `y` moved into the box.
    pub(super) fn clamp(&self, y: &[f64]) -> Vec<f64> {
        y.iter()
            .enumerate()
            .map(|(k, v)| v.clamp(self.lo[k], self.hi[k]))
            .collect()
    }

    /// Full parameter vector from log-point `y` (clamped to the box).
    pub(super) fn theta(&self, y: &[f64]) -> Vec<f64> {
        let mut t = self.theta0.clone();
        for (k, &i) in self.free.iter().enumerate() {
            t[i] = y[k].clamp(self.lo[k], self.hi[k]).exp();
        }
        t
    }

    /// The experiment's sums at parameter values `theta`: exact where asked for and
    /// available, else Monte Carlo.
    pub(super) fn accumulate(&self, theta: &[f64]) -> Accumulator {
        if !self.exact {
            return self.monte_carlo(theta, &self.mc);
        }
        let key: Vec<u64> = theta.iter().map(|v| v.to_bits()).collect();
        let memo = || self.memo.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(acc) = memo().get(&key) {
            return acc;
        }
        match self.model.expected(theta, &self.mc) {
            Some(acc) => {
                memo().insert(key, &acc);
                acc
            }
            None => self.monte_carlo(theta, &self.mc),
        }
    }

    /// J at log-point `y` plus a quadratic penalty outside the box, so that a simplex that
    /// steps out walks back in.
    pub(super) fn score(&self, y: &[f64]) -> Evaluation<f64> {
        let acc = self.accumulate(&self.theta(y));
        let j = self.objective.evaluate(&acc).total;
        let outside: f64 = y
            .iter()
            .enumerate()
            .map(|(k, v)| (self.lo[k] - v).max(0.0).powi(2) + (v - self.hi[k]).max(0.0).powi(2))
            .sum();
        let score = j + BOX_PENALTY * outside;
        Evaluation {
            j: score,
            diverged: acc.diverged_runs > 0,
            value: score,
        }
    }

    /// Whether coordinate `k` of `y` is within 0.05 log units (5%) of a bound.
    pub(super) fn near_bound(&self, k: usize, y: &[f64]) -> bool {
        y[k] - self.lo[k] < 0.05 || self.hi[k] - y[k] < 0.05
    }
}

/// What one evaluation of the cost gives: what the budget books, and what the caller asked
/// for.
pub(super) struct Evaluation<T> {
    /// The value the best point and the history are judged by (J, with the simplex's box
    /// penalty where the simplex scores).
    pub j: f64,
    /// The candidate's filter diverged.
    pub diverged: bool,
    /// The caller's value (the score, or a residual vector).
    pub value: T,
}

/// A log-point and its score: a point of the global stage, where a local search ended,
/// or the best point a budget booked.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Candidate {
    /// The log-point.
    pub point: Vec<f64>,
    /// Its score (+∞ when its filter diverged or the search found nothing finite).
    pub cost: f64,
}

/// Largest coordinate difference of two log-points (log units).
pub(super) fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::Ordering;

    use super::MEMO_ENTRIES;
    use crate::tune::tests::{Mock, cost};

    fn mock() -> Mock {
        Mock::new(&[0.3, 20.0], &[&[4.0, 2.0], &[0.0, 8.0]])
    }

    #[test]
    fn a_repeated_exact_point_is_answered_from_the_memo_with_the_same_bits() {
        let mock = mock();
        let cost = cost(&mock, &[false; 2]);
        let calls = || mock.calls.load(Ordering::SeqCst);
        let before = calls();
        let a = cost.accumulate(&[0.5, 3.0]);
        assert_eq!(calls(), before + 1);
        let again = cost.accumulate(&[0.5, 3.0]);
        assert_eq!(
            calls(),
            before + 1,
            "a repeated point is not evaluated again"
        );
        assert_eq!(format!("{a:?}"), format!("{again:?}"));
        // Another point, even one a rounding away, is evaluated.
        cost.accumulate(&[0.5, f64::from_bits(3.0f64.to_bits() + 1)]);
        assert_eq!(calls(), before + 2);
        // A point outside the box scores its clamped point: the same sums, one evaluation.
        let inside = cost.score(&[-30.0, 0.0]);
        let n = calls();
        let outside = cost.score(&[-31.0, 0.0]);
        assert_eq!(calls(), n);
        assert!(
            outside.value > inside.value,
            "the box penalty still applies"
        );
    }

    #[test]
    fn the_memo_forgets_its_oldest_point_past_its_size() {
        let mock = mock();
        let cost = cost(&mock, &[false; 2]);
        let calls = || mock.calls.load(Ordering::SeqCst);
        let point = |i: usize| [1.0 + i as f64 * 1e-3, 2.0];
        for i in 0..MEMO_ENTRIES {
            cost.accumulate(&point(i));
        }
        let n = calls();
        cost.accumulate(&point(0));
        cost.accumulate(&point(MEMO_ENTRIES - 1));
        assert_eq!(calls(), n, "every point of a full memo is kept");
        cost.accumulate(&point(MEMO_ENTRIES));
        cost.accumulate(&point(1));
        assert_eq!(
            calls(),
            n + 1,
            "the newest point kept, the second oldest still there"
        );
        cost.accumulate(&point(0));
        assert_eq!(calls(), n + 2, "the oldest point forgotten");
    }
}
