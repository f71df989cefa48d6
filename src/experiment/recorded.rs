//! A recorded experiment as an [`Experiment`]: records another program wrote, judged by the
//! same gate, reports and exit codes as a problem file.

use std::path::PathBuf;

use super::{Definition, Experiment, ExperimentError, Info, RunOptions, Source};
use crate::input::FileError;
use crate::montecarlo::{DEFAULT_LAGS, McConfig};
use crate::params::ParamSpace;
use crate::records::{Recorded, read_files};
use crate::stats::Accumulator;

/// Records of one Monte Carlo experiment, summed: an experiment without parameters whose
/// sums are the records' (N and T are theirs; asking for other runs or steps is an error).
#[derive(Debug, Clone)]
pub struct RecordsExperiment {
    definition: Definition,
    recorded: Recorded,
}

impl RecordsExperiment {
    /// Read the records in `files` (see [`read_files`], with the engines' default lags); the experiment is named by
    /// [`crate::records::experiment_name`] (the first file's stem, or for per-quantity
    /// arrays `e.npy`, `P.npy` their directory's name), its components `x1 … xn` and `<sensor>_<j>`.
    pub fn read(files: &[PathBuf]) -> Result<RecordsExperiment, FileError> {
        let recorded = read_files(files, &|steps| DEFAULT_LAGS.min(steps.saturating_sub(1)))?;
        let mc = McConfig::new(recorded.runs, recorded.steps)
            .and_then(|mc| mc.with_lags(recorded.sums.lags))
            .map_err(|e| FileError::new(&files[0], "", e.to_string()))?;
        let name = crate::records::experiment_name(files);
        Ok(RecordsExperiment {
            definition: Definition {
                info: Info {
                    name,
                    description: String::new(),
                    source: Source::Records {
                        files: files.to_vec(),
                    },
                },
                params: ParamSpace { params: Vec::new() },
                state_names: recorded.layout.default_state_names(),
                measurement_names: recorded.layout.default_measurement_names(),
                mc,
            },
            recorded,
        })
    }

    /// What was read.
    pub fn recorded(&self) -> &Recorded {
        &self.recorded
    }
}

impl Experiment for RecordsExperiment {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn monte_carlo_with(
        &self,
        _theta: &[f64],
        mc: &McConfig,
        _options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let r = &self.recorded;
        if (mc.runs(), mc.steps(), mc.lags()) != (r.runs, r.steps, r.sums.lags) {
            return Err(ExperimentError::RecordsDiffer {
                source_label: self.definition.info.source.label(),
                held: (r.runs, r.steps, r.sums.lags),
                asked: (mc.runs(), mc.steps(), mc.lags()),
            });
        }
        Ok(r.sums.clone())
    }
}

impl crate::experiment::Structure for RecordsExperiment {}

impl crate::experiment::HeldAsCode for RecordsExperiment {}

impl crate::experiment::Sampling for RecordsExperiment {
    fn truth_reuse(&self, _since: crate::montecarlo::TapeUsage) -> super::TruthReuse {
        super::TruthReuse::Recorded
    }

    fn seed_free(&self) -> bool {
        true
    }
}
