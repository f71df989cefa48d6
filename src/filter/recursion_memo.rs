//! A thread's memory of the linear Kalman filter's covariance recursion.
//!
//! The linear filter's P, K and S depend on its model and P0 only, not on the readings, so
//! every Monte Carlo run of one filter computes the same ones at each step, and that is most
//! of a run's time on the generic engine (a Rust model's filter, a filter held as code in a
//! misfit trial). Each thread keeps the last prediction and update it computed at each step
//! with the P it started from, and hands them back when a run of the same filter reaches
//! that step from the same P to the last bit. They are a pure function of those inputs, so
//! what is handed back is the same bits as computing again: no result depends on the memo.
//! A call from another filter (another Q or R) starts the memo afresh.

#![allow(non_snake_case)]

use std::cell::RefCell;

use nalgebra::DMatrix;

use crate::linalg::same_bits as same;

use super::joseph::CovarianceUpdate;
use super::{Estimate, FilterError};

/// Bytes of matrices a thread remembers at most; steps beyond are computed each time.
const MEMO_BYTES: usize = 16 << 20;

/// Steps a thread remembers at most: the slots themselves take memory before any matrix
/// (a run of a million steps would take a hundred megabytes of empty ones).
const MEMO_STEPS: usize = 1 << 14;

thread_local! {
    static MEMO: RefCell<Memo> = RefCell::new(Memo::default());
}

/// The filter whose steps are remembered: its F, Q, H and R.
pub(super) type Model<'a> = [&'a DMatrix<f64>; 4];

/// A step's input and what was computed from it.
type Slot<T> = Option<(DMatrix<f64>, T)>;

/// An update remembered: the covariance update, and the step's error map `(I − K H) F`
/// (what [`super::Estimate::compose_error_map`] makes of the map F that the prediction
/// set), computed once for all the runs instead of once per run.
#[derive(Clone)]
pub(super) struct Updated {
    pub(super) cu: CovarianceUpdate,
    pub(super) map: DMatrix<f64>,
}

#[derive(Default)]
struct Memo {
    /// The filter the steps belong to: F, Q, H, R.
    model: Option<[DMatrix<f64>; 4]>,
    /// At step k: the posterior predicted from and the prior predicted.
    predicted: Vec<Slot<DMatrix<f64>>>,
    /// At step k: the prior updated from and the update.
    updated: Vec<Slot<Updated>>,
    bytes: usize,
}

impl Memo {
    /// The memo, emptied unless it belongs to the filter `[F, Q, H, R]`.
    fn for_filter(&mut self, f: Model) -> &mut Self {
        let mine = self.model.as_ref().is_some_and(|[F, Q, H, R]| {
            same(F, f[0]) && same(Q, f[1]) && same(H, f[2]) && same(R, f[3])
        });
        if !mine {
            *self = Memo {
                model: Some(f.map(DMatrix::clone)),
                ..Memo::default()
            };
        }
        self
    }
}

/// Step k's value of `slots` where it was computed from `from`.
fn recall<'a, T>(slots: &'a [Slot<T>], k: usize, from: &DMatrix<f64>) -> Option<&'a T> {
    match slots.get(k) {
        Some(Some((input, value))) if same(input, from) => Some(value),
        _ => None,
    }
}

/// Keep `value`, computed at step k from `from`, in `slots`, where the memo's `bytes`
/// stay within [`MEMO_BYTES`] (slots of one filter are all the same size).
fn remember<T: Clone>(
    slots: &mut Vec<Slot<T>>,
    bytes: &mut usize,
    k: usize,
    from: &DMatrix<f64>,
    value: &T,
    size: usize,
) {
    if k >= MEMO_STEPS {
        return;
    }
    if slots.len() <= k {
        slots.resize_with(k + 1, || None);
    }
    if slots[k].is_none() {
        if *bytes + size > MEMO_BYTES {
            return;
        }
        *bytes += size;
    }
    slots[k] = Some((from.clone(), value.clone()));
}

fn bytes(m: &DMatrix<f64>) -> usize {
    m.len() * std::mem::size_of::<f64>()
}

/// `P` predicted at step `k` by the filter `f` (`predict(P)`), in place, remembered: a
/// step served from the memo copies into P's storage instead of allocating.
pub(super) fn predict(
    f: Model,
    k: usize,
    P: &mut DMatrix<f64>,
    predict: impl FnOnce(&DMatrix<f64>) -> DMatrix<f64>,
) {
    MEMO.with_borrow_mut(|memo| {
        let memo = memo.for_filter(f);
        if let Some(Pp) = recall(&memo.predicted, k, P) {
            if Pp.shape() == P.shape() {
                P.copy_from(Pp);
            } else {
                *P = Pp.clone();
            }
            return;
        }
        let Pp = predict(P);
        remember(
            &mut memo.predicted,
            &mut memo.bytes,
            k,
            P,
            &Pp,
            2 * bytes(P),
        );
        *P = Pp;
    })
}

/// The filter `f`'s covariance update of `est.P` at step `k` (`update(&est.P)`),
/// remembered, handed to `then` with the step's error map and the estimate (a failure is
/// not remembered: it is computed again, with its own step in the message). What is
/// handed over is borrowed from the memo, not cloned.
pub(super) fn update<R>(
    f: Model,
    k: usize,
    est: &mut Estimate,
    update: impl FnOnce(&DMatrix<f64>) -> Result<CovarianceUpdate, FilterError>,
    then: impl FnOnce(&Updated, &mut Estimate) -> R,
) -> Result<R, FilterError> {
    MEMO.with_borrow_mut(|memo| {
        let memo = memo.for_filter(f);
        if let Some(u) = recall(&memo.updated, k, &est.P) {
            return Ok(then(u, est));
        }
        let cu = update(&est.P)?;
        let map = &cu.IKH * f[0];
        let u = Updated { cu, map };
        let size = bytes(&est.P)
            + bytes(&u.cu.K)
            + 2 * bytes(&u.cu.S)
            + bytes(&u.cu.P)
            + bytes(&u.cu.IKH)
            + bytes(&u.map);
        remember(&mut memo.updated, &mut memo.bytes, k, &est.P, &u, size);
        Ok(then(&u, est))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::KalmanFilter;
    use nalgebra::DVector;

    fn key(f: &KalmanFilter) -> Model<'_> {
        [&f.F, &f.Q, &f.H, &f.R]
    }

    /// A constant-velocity filter whose noise levels are scaled by `s`.
    fn cv(s: f64) -> KalmanFilter {
        KalmanFilter {
            F: DMatrix::from_row_slice(2, 2, &[1.0, 0.1, 0.0, 1.0]),
            H: DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            Q: crate::params::dwna_block(0.1) * (0.3 * s),
            R: DMatrix::from_element(1, 1, 2.0 * s),
            x0: DVector::zeros(2),
            P0: DMatrix::from_diagonal(&DVector::from_column_slice(&[10.0, 4.0])),
        }
    }

    /// The recursion of `f` over `steps`, through the memo or computed directly: each
    /// step's prior, gain and posterior.
    fn recursion(f: &KalmanFilter, steps: usize, memo: bool) -> Vec<[DMatrix<f64>; 3]> {
        let mut P = f.P0.clone();
        (1..=steps)
            .map(|k| {
                let Pp = if memo {
                    let mut Pp = P.clone();
                    predict(key(f), k, &mut Pp, |P| f.predict_covariance(P));
                    Pp
                } else {
                    f.predict_covariance(&P)
                };
                let cu = if memo {
                    update(
                        key(f),
                        k,
                        &mut Estimate::new(&f.x0, &Pp),
                        |P| f.update_covariance(P, k),
                        |u, _| u.cu.clone(),
                    )
                } else {
                    f.update_covariance(&Pp, k)
                };
                let cu = cu.unwrap();
                P = cu.P.clone();
                [Pp, cu.K, cu.P]
            })
            .collect()
    }

    fn bits(r: &[[DMatrix<f64>; 3]]) -> Vec<u64> {
        r.iter()
            .flatten()
            .flat_map(|m| m.iter().map(|v| v.to_bits()))
            .collect()
    }

    #[test]
    fn remembered_steps_are_the_computed_bits_and_another_filter_gets_its_own() {
        let (a, b) = (cv(1.0), cv(3.0));
        let direct_a = bits(&recursion(&a, 40, false));
        let direct_b = bits(&recursion(&b, 40, false));
        assert_ne!(direct_a, direct_b);
        // Runs of a, then of b (which replaces a's steps), then of a again, and a run of
        // a that starts from another P0 (every step's input differs).
        for (f, want) in [
            (&a, &direct_a),
            (&a, &direct_a),
            (&b, &direct_b),
            (&a, &direct_a),
        ] {
            assert_eq!(&bits(&recursion(f, 40, true)), want);
        }
        let mut moved = a.clone();
        moved.P0 *= 2.0;
        assert_eq!(
            bits(&recursion(&moved, 40, true)),
            bits(&recursion(&moved, 40, false))
        );
        // The second run of a filter is served from the memo: its steps are held.
        recursion(&a, 40, true);
        MEMO.with_borrow(|m| {
            assert_eq!(m.predicted.iter().flatten().count(), 40);
            assert_eq!(m.updated.iter().flatten().count(), 40);
            assert!(m.bytes > 0 && m.bytes <= MEMO_BYTES);
        });
    }

    #[test]
    fn a_failed_update_is_not_remembered() {
        let mut f = cv(1.0);
        f.R[(0, 0)] = -1e9;
        let Pp = f.predict_covariance(&f.P0);
        for k in [3, 7] {
            match update(
                key(&f),
                k,
                &mut Estimate::new(&f.x0, &Pp),
                |P| f.update_covariance(P, k),
                |_, _| (),
            ) {
                Err(FilterError::NotPositiveDefinite { which: "S", step }) => assert_eq!(step, k),
                other => panic!("{other:?}"),
            }
        }
        MEMO.with_borrow(|m| assert_eq!(m.updated.iter().flatten().count(), 0));
    }

    #[test]
    fn steps_past_the_bound_are_computed_and_not_held() {
        let f = cv(1.0);
        let far = MEMO_STEPS + 5;
        let mut Pp = f.P0.clone();
        predict(key(&f), far, &mut Pp, |P| f.predict_covariance(P));
        assert_eq!(Pp, f.predict_covariance(&f.P0));
        update(
            key(&f),
            far,
            &mut Estimate::new(&f.x0, &Pp),
            |P| f.update_covariance(P, far),
            |_, _| (),
        )
        .unwrap();
        MEMO.with_borrow(|m| {
            assert!(m.predicted.len() <= MEMO_STEPS && m.updated.len() <= MEMO_STEPS);
            assert_eq!(m.bytes, 0);
        });
    }
}
