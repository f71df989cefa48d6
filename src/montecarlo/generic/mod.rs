//! The generic engine: any [`TruthModel`] against any [`Filter`], one run at a time.
//!
//! A run stops, recorded with its cause and reason
//! ([`StopCause`](crate::stats::StopCause)) and contributing nothing at the step it stops,
//! when its filter fails ([`FilterError`](crate::filter::FilterError), including a
//! covariance too ill-conditioned to invert: [`crate::filter::conditioning`]) or when its
//! numbers stop meaning anything ([`Fault`]): the truth state overflows, the state outgrows
//! double precision relative to the filter's standard deviation, or the NEES or NIS
//! overflows.

use nalgebra::DVector;
use rayon::prelude::*;

mod fault;
mod run;

pub(super) use fault::{Fault, MAX_RATIO_SQ};
pub use run::NULL_VAR_STRIDE;
use run::{Shape, StepBuffers, Stop, Work, one_run};

use super::tape::{Live, Replay, TruthCache, TruthSource, TruthTape};
use super::{McConfig, RunOptions, record_divergence, run_chunked};
use crate::filter::{Filter, Innovation, check_measurement};
use crate::measurement::sensor_offsets;
use crate::model::TruthModel;
use crate::stats::{Accumulator, RunRecorder};

/// Run the Monte Carlo test with any truth model and filter, one run at a time (the general
/// path: nonlinear models, filters whose gain depends on the data, changing measurements).
pub fn run_generic<M, F>(truth: &M, filter: &F, mc: &McConfig) -> Accumulator
where
    M: TruthModel + ?Sized,
    F: Filter + ?Sized,
{
    run_generic_with(truth, filter, mc, RunOptions::default())
}

/// [`run_generic`] with options: progress after each parallel wave, and a share of the
/// chunks (the engine path in the options is not read: this is the generic one).
pub fn run_generic_with<M, F>(
    truth: &M,
    filter: &F,
    mc: &McConfig,
    options: RunOptions<'_>,
) -> Accumulator
where
    M: TruthModel + ?Sized,
    F: Filter + ?Sized,
{
    run_with_tape(truth, filter, mc, options, None)
}

/// [`run_generic_with`] for a truth that does not depend on the filter's
/// parameters: a seed set evaluated before is replayed from `cache` rather than simulated
/// again (the sums are bit-identical; see [`TruthCache`]).
pub fn run_generic_cached<M, F>(
    truth: &M,
    filter: &F,
    mc: &McConfig,
    options: RunOptions<'_>,
    cache: &TruthCache,
) -> Accumulator
where
    M: TruthModel + ?Sized,
    F: Filter + ?Sized,
{
    let share = options.share.map_or(super::Share::WHOLE, |s| s.share);
    let tape = cache.tape(truth, mc, share);
    run_with_tape(truth, filter, mc, options, tape.as_deref())
}

/// The generic engine on `tape`'s runs where given (it must cover `mc`), else simulating.
fn run_with_tape<M, F>(
    truth: &M,
    filter: &F,
    mc: &McConfig,
    options: RunOptions<'_>,
    tape: Option<&TruthTape>,
) -> Accumulator
where
    M: TruthModel + ?Sized,
    F: Filter + ?Sized,
{
    let share = options.share.map_or(super::Share::WHOLE, |s| s.share);
    debug_assert!(tape.is_none_or(|t| t.covers(mc, share)));
    let n_x = filter.n_x();
    let dims = filter.sensor_dims();
    let offsets = sensor_offsets(&dims);
    let n_z: usize = dims.iter().sum();
    let shape = Shape {
        offsets: &offsets,
        dims: &dims,
    };
    let side_by_side = runs_side_by_side(mc, n_x, n_z);
    let new_work = || Work {
        recorder: RunRecorder::new(n_x, n_z, mc.lags()),
        bufs: StepBuffers::default(),
        error: DVector::zeros(n_x),
        innovation: Innovation::empty(),
        meas: Vec::new(),
    };
    let run = |run: usize, acc: &mut Accumulator, work: &mut Work| {
        work.recorder.reset();
        let done = match tape {
            Some(t) => one_run(Replay::new(t.run(run)), filter, mc, run, shape, acc, work),
            None => {
                let mut meas = std::mem::take(&mut work.meas);
                let live = Live::new(truth, mc.seed(), run, &mut meas);
                let done = one_run(live, filter, mc, run, shape, acc, work);
                work.meas = meas;
                done
            }
        };
        match done {
            Ok(()) => work.recorder.end_run(acc),
            Err(e) => {
                work.recorder.stop_run(acc);
                match e {
                    Stop::Filter(e) => record_divergence(acc, run, &e),
                    Stop::Fault(f, step) => acc.record_stop(run, step, f.cause(), f.reason(step)),
                }
                acc.runs += 1;
            }
        }
    };
    run_chunked(mc, n_x, n_z, options, |range, acc| {
        if side_by_side <= 1 {
            let mut work = new_work();
            for r in range {
                run(r, acc, &mut work);
            }
            return;
        }
        // Each run adds to every sum of the accumulator at most once (the recorder sums a
        // run's own steps first), so runs summed apart and added in run order give what
        // summing them one after the other gives, bit for bit.
        let (start, end) = (range.start, range.end);
        for first in (start..end).step_by(side_by_side) {
            let parts: Vec<Accumulator> = (first..end.min(first + side_by_side))
                .into_par_iter()
                .map_init(new_work, |work, r| {
                    let mut own = Accumulator::new(mc.steps(), n_x, n_z, mc.lags());
                    run(r, &mut own, work);
                    own
                })
                .collect();
            for p in &parts {
                acc.merge(p);
            }
        }
    })
}

/// Each measurement component's innovation standard deviation √S_jj (in the component's
/// units), averaged in S over the updates of run 0 of `mc`'s seed set: the scale of what
/// the filter reads, for changes whose size is a reading (a sensor's offset). `None` where
/// the run fails, or a component is never measured.
pub fn innovation_scales<M, F>(truth: &M, filter: &F, mc: &McConfig) -> Option<Vec<f64>>
where
    M: TruthModel + ?Sized,
    F: Filter + ?Sized,
{
    let dims = filter.sensor_dims();
    let starts = sensor_offsets(&dims);
    let n_z: usize = dims.iter().sum();
    let (mut total, mut count) = (vec![0.0; n_z], vec![0usize; n_z]);
    let mut meas = Vec::new();
    let mut live = Live::new(truth, mc.seed(), 0, &mut meas);
    let mut est = filter.initial();
    for k in 1..=mc.steps() {
        if !live.advance(k) {
            break;
        }
        match live.input() {
            Some(u) => filter.predict_with_input(k, &mut est, u).ok()?,
            None => filter.predict(k, &mut est).ok()?,
        }
        for m in live.measurements() {
            check_measurement(dims.get(m.sensor).copied(), m).ok()?;
            let i = filter.update(k, &mut est, m).ok()?;
            for j in 0..m.z.len() {
                total[starts[m.sensor] + j] += i.S[(j, j)];
                count[starts[m.sensor] + j] += 1;
            }
        }
    }
    total
        .iter()
        .zip(&count)
        .map(|(t, &c)| {
            let s = (t / c as f64).sqrt();
            (c > 0 && s.is_finite() && s > 0.0).then_some(s)
        })
        .collect()
}

/// Bytes a run's sums take, beyond its filter's own storage.
fn run_bytes(mc: &McConfig, n_x: usize, n_z: usize) -> usize {
    let per_step = 8;
    let numbers = per_step * mc.steps() + 12 * n_x + 10 * n_z + 4 * mc.lags() * n_z;
    numbers.saturating_mul(std::mem::size_of::<f64>())
}

/// At most this much memory holds runs summed apart.
const SIDE_BY_SIDE_BYTES: usize = 256 << 20;

/// How many runs of a chunk to compute side by side (1: one after the other). A chunk is
/// the unit of parallel work, so an evaluation of fewer chunks than threads (60 runs are
/// one chunk) would leave threads idle; its runs then go to the threads a few at a time,
/// each into sums of its own, added in run order. Otherwise, and when so many runs' sums
/// would not fit in [`SIDE_BY_SIDE_BYTES`], one after the other.
fn runs_side_by_side(mc: &McConfig, n_x: usize, n_z: usize) -> usize {
    let threads = rayon::current_num_threads();
    let chunks = mc.runs().div_ceil(super::CHUNK);
    if threads <= 1 || chunks >= threads {
        return 1;
    }
    let fit = SIDE_BY_SIDE_BYTES / (chunks * run_bytes(mc, n_x, n_z)).max(1);
    (2 * threads).min(fit).min(super::CHUNK)
}
