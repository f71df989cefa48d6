//! The one wrapper through which the search evaluates its cost: it counts and budgets the
//! evaluations (a number of them and a deadline), books each one (the history of the best
//! J, the best point, the diverged count), tells the [`Observer`], and owns the state of
//! having run out, as argmin's `Problem<O>` counts the calls of the function it wraps.
//!
//! Parallel work gets a budget of its own per item ([`Budget::map`]): each fork may spend
//! what the parent has left, and the parent books the forks' evaluations in item order and
//! stops booking where its own budget ends. That is what a sequential run would have
//! charged (each item's search does not depend on the cap until it hits it), so the count,
//! the history and the best point do not depend on the thread count or on scheduling.

use std::time::Instant;

use rayon::prelude::*;

use super::cost::{Candidate, Cost, Evaluation};
use super::result::{Observer, Silent};

/// An evaluation refused because the budget is spent (see [`Budget::exhausted`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Exhausted;

/// One booked evaluation.
struct Booking {
    j: f64,
    diverged: bool,
    /// The point, kept only while it is the best so far where it was booked: a point that
    /// did not lower a fork's best cannot lower the parent's either.
    point: Option<Vec<f64>>,
}

/// Counts, budgets and books every evaluation of a [`Cost`].
pub(super) struct Budget<'a> {
    cost: &'a Cost<'a>,
    max_evals: usize,
    deadline: Instant,
    observer: &'a dyn Observer,
    booked: Vec<Booking>,
    best: Option<usize>,
    exhausted: bool,
}

impl<'a> Budget<'a> {
    /// A budget of `max_evals` evaluations of `cost` until `deadline`, reporting each to
    /// `observer`.
    pub(super) fn new(
        cost: &'a Cost<'a>,
        max_evals: usize,
        deadline: Instant,
        observer: &'a dyn Observer,
    ) -> Self {
        Budget {
            cost,
            max_evals,
            deadline,
            observer,
            booked: Vec::new(),
            best: None,
            exhausted: false,
        }
    }

    /// The wrapped cost, for what is not charged (its box, and the resolution's curvature
    /// after the search).
    pub(super) fn cost(&self) -> &'a Cost<'a> {
        self.cost
    }

    /// Evaluates `f` at `y` if the budget allows, and books it.
    pub(super) fn evaluate<T>(
        &mut self,
        y: &[f64],
        f: impl FnOnce(&Cost<'a>, &[f64]) -> Evaluation<T>,
    ) -> Result<T, Exhausted> {
        if self.exhausted
            || self.best_j() < self.cost.stop_below
            || self.booked.len() >= self.max_evals
            || Instant::now() > self.deadline
            || self.cost.failure().is_some()
        {
            self.exhausted = true;
            return Err(Exhausted);
        }
        let e = f(self.cost, y);
        self.book(Booking {
            j: e.j,
            diverged: e.diverged,
            point: Some(y.to_vec()),
        });
        Ok(e.value)
    }

    /// [`Cost::score`] at `y`, charged.
    pub(super) fn score(&mut self, y: &[f64]) -> Result<f64, Exhausted> {
        self.evaluate(y, Cost::score)
    }

    /// `f` on each item, each with a budget of its own, in parallel if `parallel`; the
    /// items' evaluations are booked here in item order, up to this budget's end.
    pub(super) fn map<T: Sync, R: Send>(
        &mut self,
        items: &[T],
        parallel: bool,
        f: impl Fn(&mut Budget<'a>, &T) -> R + Sync,
    ) -> Vec<R> {
        if !parallel {
            return items.iter().map(|item| f(self, item)).collect();
        }
        let (cost, deadline, exhausted) = (self.cost, self.deadline, self.exhausted);
        let remaining = self.max_evals.saturating_sub(self.booked.len());
        let forks: Vec<(Budget<'a>, R)> = items
            .par_iter()
            .map(|item| {
                let mut fork = Budget::new(cost, remaining, deadline, &Silent);
                fork.exhausted = exhausted;
                let r = f(&mut fork, item);
                (fork, r)
            })
            .collect();
        forks
            .into_iter()
            .map(|(fork, r)| {
                self.join(fork);
                r
            })
            .collect()
    }

    /// Books a fork's evaluations after this budget's own, as far as this budget reaches.
    fn join(&mut self, fork: Budget<'_>) {
        self.exhausted |= fork.exhausted;
        for booking in fork.booked {
            if self.booked.len() >= self.max_evals {
                self.exhausted = true;
                break;
            }
            self.book(booking);
        }
    }

    fn book(&mut self, mut booking: Booking) {
        let improves = booking.j < self.best_j();
        debug_assert!(!improves || booking.point.is_some());
        if !improves {
            booking.point = None;
        }
        self.booked.push(booking);
        if improves {
            self.best = Some(self.booked.len() - 1);
        }
        self.observer.evaluation(self.booked.len(), self.best_j());
    }

    fn best_j(&self) -> f64 {
        self.best.map_or(f64::INFINITY, |i| self.booked[i].j)
    }

    /// Evaluations booked.
    pub(super) fn evaluations(&self) -> usize {
        self.booked.len()
    }

    /// Booked evaluations whose filter diverged.
    pub(super) fn diverged(&self) -> usize {
        self.booked.iter().filter(|b| b.diverged).count()
    }

    /// Whether an evaluation was refused: the search stopped on its budget.
    pub(super) fn exhausted(&self) -> bool {
        self.exhausted
    }

    /// The lowest finite J booked (the first on ties) and its point.
    pub(super) fn best(&self) -> Option<Candidate> {
        let b = &self.booked[self.best?];
        Some(Candidate {
            point: b.point.clone()?,
            cost: b.j,
        })
    }

    /// The best J after each booked evaluation.
    pub(super) fn history(&self) -> Vec<f64> {
        let mut best = f64::INFINITY;
        self.booked
            .iter()
            .map(|b| {
                if b.j < best {
                    best = b.j;
                }
                best
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::Ordering;
    use std::time::Duration;

    use super::*;
    use crate::tune::tests::{Mock, cost};

    /// The tests' quadratic, diverging where p0 > 3.
    fn mock() -> Mock {
        Mock::new(&[0.3, 20.0], &[&[4.0, 2.0], &[0.0, 8.0]]).diverging_above(0, 3.0)
    }

    fn in_an_hour() -> Instant {
        Instant::now() + Duration::from_secs(3600)
    }

    #[test]
    fn charges_max_evals_then_refuses_without_evaluating() {
        let mock = mock();
        let cost = cost(&mock, &[false; 2]);
        let mut b = Budget::new(&cost, 3, in_an_hour(), &Silent);
        for _ in 0..3 {
            assert!(b.score(&[0.0, 0.0]).is_ok());
        }
        assert!(
            !b.exhausted(),
            "spending the whole budget is not running out"
        );
        let calls = mock.calls.load(Ordering::SeqCst);
        assert_eq!(b.score(&[0.0, 0.0]), Err(Exhausted));
        assert_eq!(mock.calls.load(Ordering::SeqCst), calls);
        assert!(b.exhausted());
        assert_eq!(b.evaluations(), 3);
        assert_eq!(b.history().len(), 3);
    }

    #[test]
    fn a_passed_deadline_refuses_the_first_evaluation() {
        let mock = mock();
        let cost = cost(&mock, &[false; 2]);
        let past = Instant::now() - Duration::from_millis(1);
        let mut b = Budget::new(&cost, 100, past, &Silent);
        assert_eq!(b.score(&[0.0, 0.0]), Err(Exhausted));
        assert!(b.exhausted());
        assert_eq!(b.evaluations(), 0);
    }

    #[test]
    fn books_diverged_evaluations_the_best_point_and_the_history() {
        let mock = mock();
        let cost = cost(&mock, &[false; 2]);
        let mut b = Budget::new(&cost, 10, in_an_hour(), &Silent);
        let start = [0.0, 0.0];
        let diverging = [10f64.ln(), 0.0];
        let truth = mock.y_star();
        let j_start = b.score(&start).unwrap();
        assert_eq!(b.score(&diverging), Ok(f64::INFINITY));
        let j_truth = b.score(&truth).unwrap();
        b.score(&start).unwrap();
        assert!(j_truth < 1e-20 && j_start > 1.0, "{j_truth} {j_start}");
        assert_eq!(b.diverged(), 1);
        assert_eq!(b.history(), vec![j_start, j_start, j_truth, j_truth]);
        let best = b.best().unwrap();
        assert_eq!((best.cost, best.point), (j_truth, truth));
    }

    #[test]
    fn the_first_of_equally_good_points_stays_the_best() {
        // p0 and p1 enter only through (2/θ0)·(2/θ1), which is the same product to the
        // last bit when the two are swapped.
        let mock = Mock::new(&[2.0, 2.0], &[&[1.0, 1.0]]);
        let cost = cost(&mock, &[false; 2]);
        let mut b = Budget::new(&cost, 10, in_an_hour(), &Silent);
        let (first, second) = ([0.1, 0.3], [0.3, 0.1]);
        assert_eq!(b.score(&first), b.score(&second));
        assert_eq!(b.best().unwrap().point, first);
    }

    #[test]
    fn parallel_items_are_booked_as_a_sequential_run_would_charge_them() {
        let mock = mock();
        let cost = cost(&mock, &[false; 2]);
        // Three items of four evaluations each, walking towards the truth from different
        // sides; one step of the third diverges.
        let items = [[-1.0, 2.0], [0.5, 4.0], [2.0, 3.0]];
        let walk = |b: &mut Budget<'_>, from: &[f64; 2]| -> Result<(), Exhausted> {
            for k in 0..4 {
                let t = k as f64 / 3.0;
                let y: Vec<f64> = (0..2)
                    .map(|i| from[i] + t * (mock.y_star()[i] - from[i]))
                    .collect();
                b.score(&y)?;
            }
            Ok(())
        };
        // Budgets that run out inside the second item, end exactly with the third, and
        // have room to spare.
        for max_evals in [5, 12, 100] {
            let run = |parallel: bool| {
                let mut b = Budget::new(&cost, max_evals, in_an_hour(), &Silent);
                b.score(&[0.0, 0.0]).unwrap();
                b.map(&items, parallel, walk);
                (b.evaluations(), b.exhausted(), b.diverged(), b.history())
            };
            let (seq, par) = (run(false), run(true));
            assert_eq!(seq.0, max_evals.min(13), "max_evals {max_evals}");
            assert_eq!(seq.1, max_evals < 13, "max_evals {max_evals}");
            assert_eq!(par, seq, "max_evals {max_evals}");
        }
    }
}
