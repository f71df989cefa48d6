//! The seed contract, checked once on a worker's first evaluation: run i's records must be
//! a function of (seed, i) alone, so that any number of workers gives the same sums.

use super::ExternalExperiment;
use super::fingerprint::Fingerprints;
use super::worker::Worker;
use crate::experiment::{ExperimentError, SeedContractViolation};
use crate::montecarlo::{CHUNK, McConfig};

impl ExternalExperiment {
    /// The seed contract on the first chunk, whose runs' fingerprints are `whole`: the
    /// runs must differ from each other (not all seeded alike), and each run must come back
    /// bit for bit when asked for again, in two halves, the second half first, from
    /// another worker than the first chunk's (a fresh process where there is only one):
    /// noise drawn from a generator shared across runs or requests, or a cache that is not
    /// a function of (seed, i), then shows.
    pub(super) fn check_contract(
        &self,
        pool: &mut [Worker],
        theta: &str,
        mc: &McConfig,
        whole: &Fingerprints,
    ) -> Result<(), ExperimentError> {
        let first = 0..CHUNK.min(mc.runs());
        if first.len() < 2 {
            return Ok(());
        }
        let breaks = |violation| ExperimentError::SeedContract {
            command: self.command.display(),
            violation,
        };
        let mut prints = whole.0.values();
        if let Some(one) = prints.next()
            && whole.0.len() == first.len()
            && prints.all(|p| p == one)
        {
            return Err(breaks(SeedContractViolation::AllAlike(first)));
        }
        let mid = first.len() / 2;
        let halves = [mid..first.end, first.start..mid];
        let mut fresh = None;
        let (w, from) = if pool.len() > 1 {
            (&mut pool[1], "worker 2")
        } else {
            let w = Worker::start(&self.command.command, &self.command.dir, pool.len())
                .map_err(|why| self.start_error(true, why))?;
            (fresh.insert(w), "a fresh worker")
        };
        for half in halves {
            let mut again = Fingerprints::new();
            self.ask(w, theta, mc, half.clone(), Some(&mut again))?;
            if let Some(run) = half.clone().find(|i| again.0.get(i) != whole.0.get(i)) {
                return Err(breaks(SeedContractViolation::NotRepeatable {
                    run,
                    again: half,
                    from,
                    first,
                }));
            }
        }
        Ok(())
    }
}
