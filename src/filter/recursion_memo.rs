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

use super::FilterError;
use super::joseph::CovarianceUpdate;
use super::kf::KalmanFilter;

/// Bytes of matrices a thread remembers at most; steps beyond are computed each time.
const MEMO_BYTES: usize = 16 << 20;

thread_local! {
    static MEMO: RefCell<Memo> = RefCell::new(Memo::default());
}

#[derive(Default)]
struct Memo {
    /// The filter the steps belong to: F, Q, H, R.
    model: Option<[DMatrix<f64>; 4]>,
    /// At step k: the posterior predicted from and the prior predicted.
    predicted: Vec<Option<(DMatrix<f64>, DMatrix<f64>)>>,
    /// At step k: the prior updated from and the update.
    updated: Vec<Option<(DMatrix<f64>, CovarianceUpdate)>>,
    bytes: usize,
}

/// Whether `a` and `b` have the same shape and the same bits (−0 is not 0, a NaN equals
/// nothing a memo would hold).
fn same(a: &DMatrix<f64>, b: &DMatrix<f64>) -> bool {
    a.shape() == b.shape()
        && a.as_slice()
            .iter()
            .zip(b.as_slice())
            .all(|(x, y)| x.to_bits() == y.to_bits())
}

impl Memo {
    /// The memo, emptied unless it belongs to `f`.
    fn for_filter(&mut self, f: &KalmanFilter) -> &mut Self {
        let mine = self.model.as_ref().is_some_and(|[F, Q, H, R]| {
            same(F, &f.F) && same(Q, &f.Q) && same(H, &f.H) && same(R, &f.R)
        });
        if !mine {
            *self = Memo {
                model: Some([f.F.clone(), f.Q.clone(), f.H.clone(), f.R.clone()]),
                ..Memo::default()
            };
        }
        self
    }

    /// Room for `bytes` more, at step `k` of `slots`.
    fn room<T>(&mut self, slots: &mut Vec<Option<T>>, k: usize, bytes: usize) -> bool {
        if self.bytes + bytes > MEMO_BYTES {
            return false;
        }
        if slots.len() <= k {
            slots.resize_with(k + 1, || None);
        }
        true
    }
}

fn bytes(m: &DMatrix<f64>) -> usize {
    m.len() * std::mem::size_of::<f64>()
}

/// `f.predict_covariance(P)` at step `k`, remembered.
pub(super) fn predict(f: &KalmanFilter, k: usize, P: &DMatrix<f64>) -> DMatrix<f64> {
    MEMO.with_borrow_mut(|memo| {
        let memo = memo.for_filter(f);
        if let Some(Some((from, to))) = memo.predicted.get(k)
            && same(from, P)
        {
            return to.clone();
        }
        let Pp = f.predict_covariance(P);
        let size = 2 * bytes(P);
        let mut slots = std::mem::take(&mut memo.predicted);
        if memo.room(&mut slots, k, size) {
            if slots[k].is_none() {
                memo.bytes += size;
            }
            slots[k] = Some((P.clone(), Pp.clone()));
        }
        memo.predicted = slots;
        Pp
    })
}

/// `f.update_covariance(Pp, k)`, remembered (a failure is not: it is computed again, with
/// its own step in the message).
pub(super) fn update(
    f: &KalmanFilter,
    k: usize,
    Pp: &DMatrix<f64>,
) -> Result<CovarianceUpdate, FilterError> {
    MEMO.with_borrow_mut(|memo| {
        let memo = memo.for_filter(f);
        if let Some(Some((from, cu))) = memo.updated.get(k)
            && same(from, Pp)
        {
            return Ok(cu.clone());
        }
        let cu = f.update_covariance(Pp, k)?;
        let size = bytes(Pp) + bytes(&cu.K) + 2 * bytes(&cu.S) + bytes(&cu.P) + bytes(&cu.IKH);
        let mut slots = std::mem::take(&mut memo.updated);
        if memo.room(&mut slots, k, size) {
            if slots[k].is_none() {
                memo.bytes += size;
            }
            slots[k] = Some((Pp.clone(), cu.clone()));
        }
        memo.updated = slots;
        Ok(cu)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DVector;

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
                    predict(f, k, &P)
                } else {
                    f.predict_covariance(&P)
                };
                let cu = if memo {
                    update(f, k, &Pp)
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
            match update(&f, k, &Pp) {
                Err(FilterError::NotPositiveDefinite { which: "S", step }) => assert_eq!(step, k),
                other => panic!("{other:?}"),
            }
        }
        MEMO.with_borrow(|m| assert_eq!(m.updated.iter().flatten().count(), 0));
    }
}
