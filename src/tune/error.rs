//! Why a tuning run could not start or go on ([`TuneError`]).

use crate::experiment::ExperimentError;
use crate::input::SettingError;

/// Errors that stop a tuning run before it starts.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TuneError {
    /// A setting does not suit this experiment.
    #[error(transparent)]
    Setting(#[from] SettingError),
    /// The start or the fixed flags do not match the parameters.
    #[error("{start} start values and {fixed} fixed flags for {params} parameters")]
    Shape {
        /// Start values given.
        start: usize,
        /// Fixed flags given.
        fixed: usize,
        /// Parameters of the experiment.
        params: usize,
    },
    /// The experiment itself failed (an external worker broke the protocol).
    #[error(transparent)]
    Experiment(#[from] ExperimentError),
}
