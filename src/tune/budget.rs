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

use super::cost::Cost;
use super::result::{Observer, Silent};

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
        if self.exhausted || self.booked.len() >= self.max_evals || Instant::now() > self.deadline {
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
    pub(super) fn best(&self) -> Option<(f64, &[f64])> {
        let b = &self.booked[self.best?];
        Some((b.j, b.point.as_deref()?))
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

