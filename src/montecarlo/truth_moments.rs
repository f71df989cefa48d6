//! The truth's own moments for the exact scoring ([`super::expected`]): the second moment
//! that stops a test where the Monte Carlo runs would, and the step-by-step moments a
//! search shares between its candidates ([`TruthTrack`]).

#![allow(non_snake_case)]

use std::sync::{Arc, Mutex};

use nalgebra::{DMatrix, DVector};

use super::generic::Fault;
use crate::filter::{Filter, KalmanFilter};
use crate::linalg::products::Sparse;
use crate::model::LinearGaussianModel;
use crate::statespace::LinearGaussian;

/// Relative change of every per-step expected value below which a step counts as quiet
/// (and the truth's second moment as settled).
pub(super) const STEADY_RTOL: f64 = 1e-12;

/// The truth's second moment `E[x_k x_k']`, propagated until it settles (a stable truth)
/// or stops the test (an unstable one), and the map to the filter's states.
pub(super) struct TruthMoment {
    /// `E[x x']`, n_t × n_t; `None` once settled.
    x2: Option<DMatrix<f64>>,
    f: Sparse,
    q: DMatrix<f64>,
    /// The map's rows (n_e × n_t), `None` for the identity.
    map: Option<Sparse>,
}

impl TruthMoment {
    pub(super) fn new(truth: &LinearGaussianModel, map: Option<&DMatrix<f64>>) -> Self {
        TruthMoment {
            x2: Some(&truth.P0 + &truth.x0 * truth.x0.transpose()),
            f: Sparse::new(&truth.F),
            q: truth.Q.clone(),
            map: map.map(Sparse::new),
        }
    }

    /// Advance to the next step, whose filter covariance is `P` and expected normalized
    /// errors `E[e_j²] / P_jj` are `comp_x`: the [`Fault`] that stops the runs there, as the
    /// Monte Carlo engines judge it with the truth's root mean square in place of one run's
    /// estimate.
    fn step(&mut self, P: &DMatrix<f64>, comp_x: &[f64]) -> Option<Fault> {
        let x2 = self.x2.as_ref()?;
        let mut next = self.f.sandwich(x2, &self.f) + &self.q;
        crate::linalg::symmetrize(&mut next);
        if next.iter().any(|v| !v.is_finite()) {
            return Some(Fault::TruthOverflow);
        }
        // The truth's mean square on the filter's judged states: diag(M E[x x'] M').
        let seen = |j: usize| match &self.map {
            Some(m) => m.row_quadratic(j, &next),
            None => next[(j, j)],
        };
        if let Some(fault) = resolution_fault(seen, P, comp_x) {
            return Some(fault);
        }
        let settled = x2.iter().zip(next.iter()).all(|(a, b)| {
            (a - b).abs() <= STEADY_RTOL * a.abs().max(b.abs()).max(f64::MIN_POSITIVE)
        });
        self.x2 = (!settled).then_some(next);
        None
    }
}

/// Where the truth's mean square on judged state j is `seen(j)`: the fault that stops the
/// runs when it has outgrown double precision relative to the filter's `P` (`comp_x`: the
/// expected normalized errors), as the Monte Carlo engines judge one run's estimate.
fn resolution_fault(
    seen: impl Fn(usize) -> f64,
    P: &DMatrix<f64>,
    comp_x: &[f64],
) -> Option<Fault> {
    Fault::resolution(comp_x.len(), |j| seen(j) / (P[(j, j)] * comp_x[j].max(1.0)))
}

/// The truth's second moment, to stop where the Monte Carlo runs would: a truth that
/// overflows or outgrows double precision relative to the filter's P ([`Fault`]). The error
/// moments stay bounded for a truth-matched filter on an unstable model, so without this
/// the exact path would grade a test no run can carry out.
pub(super) enum Truth<'a> {
    /// Propagated here, until it settles (the matched models' path).
    Propagated(Box<TruthMoment>),
    /// Read from the truth's track (the joint path).
    Tracked(&'a TruthTrack),
}

impl Truth<'_> {
    /// The fault at step `k` (from 1) before anything is computed there: the truth's
    /// moments overflowed.
    pub(super) fn overflows(&self, k: usize) -> Option<Fault> {
        match self {
            Truth::Propagated(_) => None,
            Truth::Tracked(t) => (k > t.steps.len()).then_some(Fault::TruthOverflow),
        }
    }

    /// The fault at step `k` once its filter covariance `P` and expected normalized errors
    /// `comp_x` are known.
    pub(super) fn step(&mut self, k: usize, P: &DMatrix<f64>, comp_x: &[f64]) -> Option<Fault> {
        match self {
            Truth::Propagated(m) => m.step(P, comp_x),
            Truth::Tracked(t) => {
                let seen = &t.steps[k - 1].seen;
                resolution_fault(|j| seen[j], P, comp_x)
            }
        }
    }
}

/// A linear truth's own moments at every step, which no filter changes: a search that
/// scores many filters against one truth (a misfit trial's) computes them once. Built for
/// one map `M` (n_e × n_t) from the truth's states to the judged ones.
#[derive(Debug, Clone)]
pub struct TruthTrack {
    /// The truth it was built for: a track is only ever read for that truth (an
    /// experiment's truth is a public field, and a clone may be given another one).
    truth: LinearGaussian,
    pub(super) map: DMatrix<f64>,
    /// Steps 1, 2, … up to the one asked for, or to the one before the truth overflows.
    pub(super) steps: Vec<TruthStep>,
    /// The steps asked for.
    pub(super) wanted: usize,
}

/// The [`TruthTrack`] a search's evaluations share, built at the first and rebuilt when one
/// needs more steps or another map than it holds (a one-step probe may come first).
#[derive(Debug, Default)]
pub struct SharedTrack(Mutex<Option<Arc<TruthTrack>>>);

impl SharedTrack {
    /// The track of `truth` for filter `f` judged through `map`, over `steps` steps.
    pub fn get(
        &self,
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        map: Option<&DMatrix<f64>>,
        steps: usize,
    ) -> Arc<TruthTrack> {
        let judged = TruthTrack::judged_map(truth, f, map);
        // A poisoned lock only means another evaluation panicked; the track is still whole.
        let mut held = self.0.lock().unwrap_or_else(|e| e.into_inner());
        match held.as_ref() {
            Some(t) if t.serves(truth, &judged, steps) => Arc::clone(t),
            _ => {
                let want = held.as_ref().map_or(steps, |t| t.wanted.max(steps));
                let t = Arc::new(TruthTrack::new(truth, f, map, want));
                *held = Some(Arc::clone(&t));
                t
            }
        }
    }
}

impl Clone for SharedTrack {
    fn clone(&self) -> Self {
        let held = self.0.lock().unwrap_or_else(|e| e.into_inner());
        SharedTrack(Mutex::new(held.clone()))
    }
}

/// The truth's moments after one step's propagation (the truth is never updated).
#[derive(Debug, Clone)]
pub(super) struct TruthStep {
    /// `E[x]`, n_t.
    pub(super) mean: DVector<f64>,
    /// `Cov(x)`, n_t × n_t.
    pub(super) cov: DMatrix<f64>,
    /// `E[x x'] H'`, n_t × m.
    pub(super) m2_ht: DMatrix<f64>,
    /// `H E[x]`, m.
    pub(super) h_mean: DVector<f64>,
    /// `M Cov(x) M'`, n_e × n_e, and `M E[x]`, n_e.
    pub(super) map_cov: DMatrix<f64>,
    pub(super) map_mean: DVector<f64>,
    /// `diag(M E[x x'] M')`, the truth's mean square on the judged states.
    pub(super) seen: Vec<f64>,
}

impl TruthTrack {
    /// The moments of `truth` over `steps` steps, for filter `f` judged through `map`
    /// (n_e × n_t; `None`: the first states of both).
    pub fn new(
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        map: Option<&DMatrix<f64>>,
        steps: usize,
    ) -> Self {
        let map = Self::judged_map(truth, f, map);
        let (f, h, m) = (
            Sparse::new(&truth.F),
            Sparse::new(&truth.H),
            Sparse::new(&map),
        );
        let mut mean = truth.x0.clone();
        let mut cov = truth.P0.clone();
        let mut out = Vec::with_capacity(steps);
        for _ in 0..steps {
            mean = &truth.F * &mean;
            cov = f.sandwich(&cov, &f) + &truth.Q;
            crate::linalg::symmetrize(&mut cov);
            let m2 = &cov + &mean * mean.transpose();
            if m2.iter().any(|v| !v.is_finite()) {
                break;
            }
            let mut map_cov = m.sandwich(&cov, &m);
            crate::linalg::symmetrize(&mut map_cov);
            let map_mean = &map * &mean;
            out.push(TruthStep {
                m2_ht: h.right_tr(&m2),
                h_mean: &truth.H * &mean,
                seen: (0..map.nrows()).map(|j| m.row_quadratic(j, &m2)).collect(),
                map_cov,
                map_mean,
                mean: mean.clone(),
                cov: cov.clone(),
            });
        }
        TruthTrack {
            truth: truth.model.clone(),
            map,
            steps: out,
            wanted: steps,
        }
    }

    /// The map the error of `f` is judged through: `map`, or, without one, the first states
    /// of both.
    pub(super) fn judged_map(
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        map: Option<&DMatrix<f64>>,
    ) -> DMatrix<f64> {
        map.cloned()
            .unwrap_or_else(|| DMatrix::identity(f.n_x(), truth.F.nrows()))
    }

    /// Whether it holds the moments a test of `truth` over `steps` steps judged through
    /// `map` reads.
    pub(super) fn serves(
        &self,
        truth: &LinearGaussianModel,
        map: &DMatrix<f64>,
        steps: usize,
    ) -> bool {
        steps <= self.wanted && *map == self.map && self.truth == truth.model
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::montecarlo::{McConfig, expected_accumulator_mapped, expected_accumulator_tracked};
    use crate::params::dwna_block;

    /// A constant-velocity truth whose process noise is `q` times the unit block.
    fn truth(q: f64) -> LinearGaussianModel {
        LinearGaussianModel::new(
            DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]),
            DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            dwna_block(1.0) * q,
            DMatrix::from_element(1, 1, 1.0),
            DVector::from_column_slice(&[0.0, 1.0]),
            DMatrix::from_diagonal(&DVector::from_column_slice(&[4.0, 1.0])),
        )
        .unwrap()
    }

    /// A filter built for a step of 1.2 instead of the truth's 1: its model is not the
    /// truth's, so the joint moments read the track.
    fn filter(t: &LinearGaussianModel) -> KalmanFilter {
        KalmanFilter {
            F: DMatrix::from_row_slice(2, 2, &[1.0, 1.2, 0.0, 1.0]),
            H: t.H.clone(),
            Q: dwna_block(1.2) * 0.3,
            R: DMatrix::from_element(1, 1, 2.0),
            x0: t.x0.clone(),
            P0: t.P0.clone(),
        }
    }

    #[test]
    fn a_shared_track_serves_only_the_truth_it_was_built_for() {
        let mc = McConfig::new(10, 40).unwrap();
        let shared = SharedTrack::default();
        let (a, b) = (truth(0.5), truth(2.0));
        for t in [&a, &b, &a] {
            let f = filter(t);
            let track = shared.get(t, &f, None, mc.steps());
            assert!(track.serves(t, &TruthTrack::judged_map(t, &f, None), mc.steps()));
            // Through the shared track: the same sums, to the bit, as built afresh.
            let through = expected_accumulator_tracked(t, &f, None, &mc, Some(&track)).unwrap();
            let fresh = expected_accumulator_mapped(t, &f, None, &mc).unwrap();
            assert_eq!(through, fresh);
        }
        // A track built for one truth is not read for another with the same map and steps.
        let f = filter(&a);
        let track = shared.get(&a, &f, None, mc.steps());
        assert!(!track.serves(&b, &track.map, mc.steps()));
        assert!(!track.serves(&a, &track.map, mc.steps() + 1));
    }
}
