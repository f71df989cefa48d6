//! A linear filter run over recorded measurements as an [`Experiment`]: no truth, so the
//! statistics are the innovations' (NIS, per-component `ν_j²/S_jj`, whiteness), one run per
//! recorded sequence. `autotune tune PROBLEM --measurements FILE` tunes against a field
//! record with the same search, confirmation and reports as against a simulation.

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use super::MeasurementRecord;
use crate::experiment::{
    Covariances, Definition, Experiment, ExperimentError, LinearExperiment, RunOptions,
};
use crate::input::SettingError;
use crate::linalg::cholesky;
use crate::montecarlo::{Engine, McConfig};
use crate::params::Target;
use crate::stats::{Accumulator, RunRecorder, StopCause};

/// A linear problem's filter and a measurement record.
pub struct ReplayExperiment {
    definition: Definition,
    problem: LinearExperiment,
    data: MeasurementRecord,
}

impl ReplayExperiment {
    /// The filter of `problem` over `data` (whose dimension the caller checked against the
    /// filter's H). The Monte Carlo settings become one run per sequence and the longest
    /// sequence's steps.
    pub fn new(problem: &LinearExperiment, data: MeasurementRecord) -> Result<Self, SettingError> {
        let mut definition = problem.definition.clone();
        let steps = data.sequences.iter().map(|s| s.steps).max().unwrap_or(0);
        definition.mc = definition
            .mc
            .with_runs(data.sequences.len())?
            .with_steps(steps)?;
        Ok(ReplayExperiment {
            definition,
            problem: problem.clone(),
            data,
        })
    }

    /// The record.
    pub fn data(&self) -> &MeasurementRecord {
        &self.data
    }
}

impl Experiment for ReplayExperiment {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    /// The filter at `theta` over every recorded sequence (the seed and the number of runs
    /// of `mc` do not apply: the data are what they are); steps beyond `mc`'s are not read.
    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        _options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let kf = self.problem.filter_at(theta);
        let (F, H, Q, R) = (&kf.F, &kf.H, &kf.Q, &kf.R);
        let m = self.data.dim;
        let n = F.nrows();
        let steps = mc.steps();
        // The state components stay empty (no truth); the sums keep their slots so that the
        // report lines up with the problem's state names.
        let mut acc = Accumulator::new(steps, self.definition.state_names.len(), m, mc.lags());
        let mut rec = RunRecorder::new(0, m, mc.lags());
        let eye = DMatrix::<f64>::identity(n, n);
        for (i, seq) in self.data.sequences.iter().enumerate() {
            rec.reset();
            let mut x = kf.x0.clone();
            let mut P = kf.P0.clone();
            let mut stopped = false;
            for (k, zk) in seq.z.chunks(m).take(steps).enumerate() {
                let step = k + 1;
                x = F * &x;
                P = F * &P * F.transpose() + Q;
                let rows: Vec<usize> = (0..m).filter(|&j| zk[j].is_finite()).collect();
                if rows.is_empty() {
                    rec.end_step(&mut acc);
                    continue;
                }
                let Hr = H.select_rows(&rows);
                let Rr = R.select_rows(&rows).select_columns(&rows);
                let S = &Hr * &P * Hr.transpose() + &Rr;
                let Some(chol) = cholesky(&S) else {
                    rec.stop_run(&mut acc);
                    acc.record_stop(
                        i,
                        step,
                        StopCause::Diverged,
                        format!("S is not positive definite at step {step}"),
                    );
                    acc.runs += 1;
                    stopped = true;
                    break;
                };
                let nu = DVector::from_iterator(rows.len(), rows.iter().map(|&j| zk[j])) - &Hr * &x;
                let w = chol.solve(&nu);
                acc.add_nis(k, nu.dot(&w), rows.len() as f64);
                for (r, &j) in rows.iter().enumerate() {
                    rec.innovation(j, nu[r] / S[(r, r)].sqrt());
                }
                rec.end_step(&mut acc);
                let K = &P * Hr.transpose() * chol.inverse();
                x += &K * &nu;
                let ikh = &eye - &K * &Hr;
                P = &ikh * &P * ikh.transpose() + &K * &Rr * K.transpose();
            }
            if !stopped {
                rec.end_run(&mut acc);
            }
        }
        Ok(acc)
    }
}

impl crate::experiment::Structure for ReplayExperiment {
    fn supports(&self, engine: Engine) -> bool {
        engine != Engine::Linear
    }

    fn target(&self, i: usize) -> Option<Target> {
        self.problem.target(i)
    }

    fn covariances(&self, theta: &[f64]) -> Option<Covariances> {
        self.problem.covariances(theta)
    }
}

impl crate::experiment::HeldAsCode for ReplayExperiment {}

impl crate::experiment::Sampling for ReplayExperiment {
    fn truth_reuse(&self, _since: crate::montecarlo::TapeUsage) -> crate::experiment::TruthReuse {
        crate::experiment::TruthReuse::Recorded
    }

    fn seed_free(&self) -> bool {
        true
    }
}
