//! A worker's filter replayed over a measurement record: the worker is handed the record's
//! path and θ, runs its own filter over each sequence, and answers with the innovations'
//! records (`"replays": true`). As an [`Experiment`] it is judged by those innovations, as
//! `check --measurements` and `tune --measurements` judge a filter autotune holds; its
//! `−log L` is what `estimate` maximizes.

use std::path::{Path, PathBuf};

use super::worker::{Reply, Request};
use super::{ExternalExperiment, answer, shut_down};
use crate::experiment::{
    Definition, Experiment, ExperimentError, RunOptions, TruthReuse, WorkerFailure,
};
use crate::input::SettingError;
use crate::montecarlo::McConfig;
use crate::params::Target;
use crate::records::WireError;
use crate::stats::Accumulator;
use std::sync::atomic::Ordering;

impl ExternalExperiment {
    /// The worker's filter at `theta` replayed over the measurement record at `record` (its
    /// `sequences` sequences of `steps` steps): the innovations' sums, as `--measurements`
    /// judges them, and their `−log L` (`None` where the worker's records carry no S, or a
    /// sequence stopped). One request to one worker, whose runs are the record's sequences;
    /// it must answer `"replays": true`.
    pub fn replay(
        &self,
        theta: &[f64],
        record: &Path,
        sequences: usize,
        mc: &McConfig,
    ) -> Result<(Accumulator, Option<f64>), ExperimentError> {
        if let Some(e) = self.failure() {
            return Err(e);
        }
        let mut pool = self.pool.lock().unwrap_or_else(|p| p.into_inner());
        // The whole pool, as an evaluation starts it: a later simulation request (a tune
        // from a start estimated on the record) finds its workers.
        self.fill(&mut pool)?;
        let path = serde_json::to_string(&record.to_string_lossy()).expect("a string serializes");
        let sums_fields = answer::request_fields(&self.layout, mc.lags());
        let theta = self.theta_json(theta);
        let req = Request {
            id: self.next_id.fetch_add(1, Ordering::Relaxed),
            theta: &theta,
            seed: mc.seed(),
            runs: 0..sequences,
            steps: mc.steps(),
            lags: mc.lags(),
            sums_fields: &sums_fields,
            replay: Some(&path),
        };
        let w = &mut pool[0];
        let mut sink = self.sink(mc, 0..sequences);
        let answered = w
            .request(&req, &self.layout, &mut sink, self.command.timeout)
            .and_then(|reply| match reply {
                Reply { replays: false, .. } => Err(WorkerFailure::NotReplaying),
                // Inline records and then sums would count runs twice.
                Reply { sums: Some(_), .. } if sink.runs() > 0 => {
                    Err(WorkerFailure::Sums(WireError::AfterRecords))
                }
                Reply {
                    sums: Some(chunk), ..
                } => Ok((chunk.sums, None)),
                Reply { sums: None, .. } => {
                    sink.finish_with_likelihood().map_err(WorkerFailure::from)
                }
            });
        // A replay says nothing of the worker's simulations: `replays` (seed-free runs) is
        // set by the answers to simulation requests alone.
        let result = answered.map_err(|failure| self.error(w, &req, failure));
        if let Err(e) = &result {
            shut_down(&mut pool);
            *self.failed.lock().unwrap_or_else(|p| p.into_inner()) = Some(e.clone());
        }
        result
    }
}

/// The filter of a worker over one measurement record of `sequences` sequences of `steps`
/// steps each.
pub struct WorkerReplay<'a> {
    worker: &'a ExternalExperiment,
    record: PathBuf,
    definition: Definition,
}

impl<'a> WorkerReplay<'a> {
    /// The filter of `worker` over the record at `record` (made absolute: the worker runs in
    /// its problem's directory), of `sequences` sequences of `steps` steps.
    pub fn new(
        worker: &'a ExternalExperiment,
        record: &Path,
        sequences: usize,
        steps: usize,
    ) -> Result<Self, SettingError> {
        let record = std::path::absolute(record).map_err(|e| {
            SettingError::new("--measurements", format!("{}: {e}", record.display()))
        })?;
        let mut definition = worker.definition().clone();
        definition.mc = definition
            .mc
            .with_runs(sequences)
            .and_then(|mc| mc.with_steps(steps))?;
        Ok(WorkerReplay {
            worker,
            record,
            definition,
        })
    }

    /// The worker failure that stopped this replay's workers, if one has (a search that
    /// reads a failure as "no likelihood here" asks this after it).
    pub fn failure(&self) -> Option<ExperimentError> {
        self.worker.failure()
    }

    /// `−log L` of the record under the worker's filter at `theta`, from the innovations
    /// and covariances it answers (`½ Σ (log det S + ν'S⁻¹ν + m log 2π)`); `Ok(None)` where
    /// its records give no S or a sequence stopped (no likelihood there).
    pub fn neg_log_likelihood(&self, theta: &[f64]) -> Result<Option<f64>, ExperimentError> {
        let mc = &self.definition.mc;
        self.worker
            .replay(theta, &self.record, mc.runs(), mc)
            .map(|(_, nll)| nll)
    }
}

impl Experiment for WorkerReplay<'_> {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    /// The worker's filter at `theta` over every sequence of the record (`mc`'s seed and
    /// runs do not apply: the data are what they are).
    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        _options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let own = &self.definition.mc;
        let mc = own.with_lags(mc.lags()).unwrap_or(*own);
        self.worker
            .replay(theta, &self.record, own.runs(), &mc)
            .map(|(acc, _)| acc)
    }
}

impl crate::experiment::Structure for WorkerReplay<'_> {
    fn truth_values(&self) -> Option<Vec<f64>> {
        self.worker.truth_values()
    }

    fn target(&self, i: usize) -> Option<Target> {
        self.worker.target(i)
    }
}

impl crate::experiment::HeldAsCode for WorkerReplay<'_> {}

impl crate::experiment::Sampling for WorkerReplay<'_> {
    fn truth_reuse(&self, _since: crate::montecarlo::TapeUsage) -> TruthReuse {
        TruthReuse::Recorded
    }

    fn seed_free(&self) -> bool {
        true
    }
}
