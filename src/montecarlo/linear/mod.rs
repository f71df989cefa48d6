//! The linear fast path: for a linear filter measured on a fixed schedule, P_k, S_k and
//! K_k do not depend on the data, so they are computed once per evaluation and every run
//! only propagates its mean. Runs are processed a chunk at a time as the rows of B × n
//! matrices, so each step is a handful of products whose inner loops run over the B runs,
//! instead of B·(several) tiny matrix-vector products with their per-call overhead.

#![allow(non_snake_case)]

use std::ops::Range;

use nalgebra::DMatrix;

mod chunk;
mod kernels;
mod schedule;

use chunk::{Job, run_chunk};
use schedule::Schedule;
pub(super) use schedule::{STEADY_STEPS, same_covariance};

use super::{McConfig, RunOptions, run_chunked};
use crate::filter::{Filter, KalmanFilter};
use crate::model::LinearGaussianModel;
use crate::stats::{Accumulator, GateMode};

/// Run the Monte Carlo test of a linear Kalman filter against a linear-Gaussian truth.
///
/// Gives the same statistics as [`super::run_generic`] on the same pair (to rounding: the
/// random draws are the same, the arithmetic is reordered), several times faster.
pub fn run_linear(
    truth: &LinearGaussianModel,
    filter: &KalmanFilter,
    mc: &McConfig,
) -> Accumulator {
    run_linear_with(truth, filter, None, mc, RunOptions::default())
}

/// [`run_linear`] for a filter whose state is `map · x_true` (n_f × n_t; `None`: the
/// truth's state), the NEES taken on `map · x_true − x̂`, with options: progress after each
/// parallel wave, and a share of the chunks (the engine path in the options is not read).
/// A run whose numbers stop meaning anything (the truth overflows, the
/// state outgrows double precision, the NEES or NIS overflows) stops there as a divergence,
/// as on the generic path.
pub fn run_linear_with(
    truth: &LinearGaussianModel,
    filter: &KalmanFilter,
    map: Option<&DMatrix<f64>>,
    mc: &McConfig,
    options: RunOptions<'_>,
) -> Accumulator {
    // A map with fewer rows than the filter has states judges its first ones only.
    let n = map.map_or(filter.n_x(), |m| m.nrows());
    let m = filter.H.nrows();
    let map_t = map.map(|m| m.transpose());
    match Schedule::compute(filter, mc.steps(), mc.gate() == GateMode::Full, n) {
        Ok(sched) => run_chunked(mc, n, m, options, |range, acc| {
            let job = Job {
                truth,
                f: filter,
                map_t: map_t.as_ref(),
                sched: &sched,
                mc,
            };
            run_chunk_dispatch(&job, range, acc)
        }),
        // The covariance recursion is the same in every run, so every run stops at the same
        // step.
        Err(e) => super::all_stopped_with(mc, n, m, &e, options),
    }
}

/// [`run_chunk`] compiled for AVX2 where the CPU has it (checked at run time), else for the
/// baseline. The arithmetic is the same element by element (Rust never fuses a multiply and
/// an add on its own, and every reduction has a fixed order), so results are identical;
/// only the vector width changes.
fn run_chunk_dispatch(job: &Job<'_>, range: Range<usize>, acc: &mut Accumulator) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        unsafe { run_chunk_avx2(job, range, acc) };
        return;
    }
    run_chunk(job, range, acc);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn run_chunk_avx2(job: &Job<'_>, range: Range<usize>, acc: &mut Accumulator) {
    run_chunk(job, range, acc);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::dwna_block;
    use nalgebra::DVector;

    #[test]
    fn avx2_build_gives_the_same_sums_as_the_baseline() {
        let F = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]);
        let H = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
        let truth = LinearGaussianModel::new(
            F.clone(),
            H.clone(),
            dwna_block(1.0) * 0.5,
            DMatrix::from_element(1, 1, 1.0),
            DVector::from_column_slice(&[0.0, 1.0]),
            DMatrix::from_diagonal(&DVector::from_column_slice(&[4.0, 1.0])),
        )
        .unwrap();
        let kf = KalmanFilter {
            F,
            H,
            Q: dwna_block(1.0) * 0.2,
            R: DMatrix::from_element(1, 1, 2.0),
            x0: truth.x0.clone(),
            P0: truth.P0.clone(),
        };
        let mc = McConfig::new(100, 50)
            .unwrap()
            .with_seed(7)
            .with_lags(3)
            .unwrap();
        let sched = Schedule::compute(&kf, mc.steps(), true, kf.n_x()).unwrap();
        let mut base = Accumulator::new(50, 2, 1, 3);
        let job = Job {
            truth: &truth,
            f: &kf,
            map_t: None,
            sched: &sched,
            mc: &mc,
        };
        run_chunk(&job, 0..100, &mut base);
        let mut fast = Accumulator::new(50, 2, 1, 3);
        run_chunk_dispatch(&job, 0..100, &mut fast);
        assert_eq!(base, fast);
        assert!(base.nees_sum.iter().all(|v| *v > 0.0));
    }
}
