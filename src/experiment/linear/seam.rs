//! The linear experiment as an [`Experiment`]: the linear engine (or the generic one),
//! the exact expected statistics, the parameters' targets and covariances.

use super::model::{LinearExperiment, Mapped};
use crate::experiment::{Block, Covariances, Definition, Experiment, ExperimentError, RunOptions};
use crate::filter::Filter;
use crate::montecarlo::{self, Engine, McConfig, expected_accumulator_tracked, models_match};
use crate::params::{NoiseKind, Target};
use crate::stats::Accumulator;

impl Experiment for LinearExperiment {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        run: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let kf = self.filter_at(theta);
        let map = self.filter.map.as_ref();
        Ok(match (run.engine, map) {
            (Engine::Auto | Engine::Linear, _) => {
                montecarlo::run_linear_with(&self.truth, &kf, map, mc, run)
            }
            (Engine::Generic, None) => montecarlo::run_generic_with(&self.truth, &kf, mc, run),
            (Engine::Generic, Some(map)) => {
                montecarlo::run_generic_with(&self.truth, &Mapped { kf: &kf, map }, mc, run)
            }
        })
    }
}

impl crate::experiment::Structure for LinearExperiment {
    fn linear(&self) -> Option<&LinearExperiment> {
        Some(self)
    }

    fn supports(&self, _engine: Engine) -> bool {
        true
    }

    fn expected(&self, theta: &[f64], mc: &McConfig) -> Option<Accumulator> {
        let kf = self.filter_at(theta);
        let map = self.filter.map.as_ref();
        // Only the joint moments read the truth's own (the matched recursion needs none).
        let track = (map.is_some() || !models_match(&self.truth, &kf))
            .then(|| self.track.get(&self.truth, &kf, map, mc.steps()));
        Some(
            expected_accumulator_tracked(&self.truth, &kf, map, mc, track.as_deref())
                .unwrap_or_else(|e| montecarlo::all_stopped(mc, kf.F.nrows(), kf.H.nrows(), &e)),
        )
    }

    fn target(&self, i: usize) -> Option<Target> {
        Some(if self.filter.q.uses(i) {
            Target {
                kind: NoiseKind::Process,
                components: self.filter.q.touched(i),
            }
        } else {
            Target {
                kind: NoiseKind::Measurement,
                components: self.filter.r.touched(i),
            }
        })
    }

    fn blocks(&self) -> Option<Vec<Block>> {
        let blocks = self.decoupled_blocks();
        (blocks.len() > 1).then_some(blocks)
    }

    fn covariances(&self, theta: &[f64]) -> Option<Covariances> {
        Some(Covariances {
            Q: self.filter.q.build(theta),
            R: self.filter.r.build(theta),
        })
    }
}

impl crate::experiment::HeldAsCode for LinearExperiment {
    fn replay_filter(&self, theta: &[f64]) -> Option<Box<dyn Filter + '_>> {
        Some(Box::new(self.filter_at(theta)))
    }

    fn simulation_truth(&self) -> Option<&dyn crate::model::TruthModel> {
        Some(&self.truth)
    }
}

impl crate::experiment::Sampling for LinearExperiment {
    fn truth_reuse(&self, _since: crate::montecarlo::TapeUsage) -> crate::experiment::TruthReuse {
        crate::experiment::TruthReuse::Simulated {
            why: "a linear problem's engine simulates the truth with the filter, the runs batched, which costs less than a replay would".to_string(),
        }
    }
}
