//! Why a command could not do its job: bad input, a refused option, an output that could
//! not be written, an experiment that could not run. Each renders as one line naming the
//! file and field, or the option; the command line exits 2 on any of them.

use crate::estimate::EstimateError;
use crate::experiment::ExperimentError;
use crate::input::{FileError, SettingError};
use crate::output::WriteError;

/// Why a command could not do its job.
#[derive(Debug, thiserror::Error)]
pub enum CommandError {
    /// A bad input file, named with its field.
    #[error(transparent)]
    File(#[from] FileError),
    /// A refused option: the option as the command line spells it (`--runs`) and why.
    #[error("{option}: {message}")]
    Option {
        /// The option, e.g. `--runs`.
        option: String,
        /// What is wrong with its value.
        message: String,
    },
    /// An output that could not be written (or would overwrite what it must not).
    #[error(transparent)]
    Write(#[from] WriteError),
    /// The experiment could not run: an external worker broke the protocol, records were
    /// malformed.
    #[error(transparent)]
    Experiment(#[from] ExperimentError),
    /// An estimate from recorded measurements failed on `subject` (the record, or where
    /// a start estimate came from).
    #[error("{subject}: {source}")]
    Estimate {
        /// What the estimate ran on, as the message names it.
        subject: String,
        /// Why it failed.
        source: EstimateError,
    },
    /// The truth of a model defined in a program or by records overflowed: nothing about
    /// its filter was tested. (A problem file's overflow is a [`CommandError::File`] error
    /// of its `[truth]` or `[model]`.)
    #[error("{subject}: {message}")]
    TruthOverflow {
        /// The program or the records, as reports name them.
        subject: String,
        /// How many runs overflowed, and the first.
        message: String,
    },
    /// The tuner refused a combination of settings for this experiment.
    #[error(transparent)]
    Tune(crate::tune::TuneError),
    /// The output path exists and the command does not overwrite what it did not create.
    #[error("{path} already exists (use --force to overwrite it)")]
    Exists {
        /// The path, as given.
        path: String,
    },
}

impl CommandError {
    /// A refusal of `option`.
    pub fn option(option: &str, message: impl Into<String>) -> CommandError {
        CommandError::Option {
            option: option.to_string(),
            message: message.into(),
        }
    }

    /// A setter's refusal as an error of the option that gave the value.
    pub fn of_option(option: &str) -> impl Fn(SettingError) -> CommandError + '_ {
        move |e| CommandError::option(option, e.message)
    }
}
