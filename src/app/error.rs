//! Why a command could not do its job ([`AppError`], exit code 2).

use crate::commands::CommandError;
use crate::experiment::ExperimentError;
use crate::input::FileError;
use crate::output::WriteError;

/// Why a command could not do its job (exit code 2). Each renders as one line naming the
/// file and field, or the flag.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// A command's refusal or failure: a bad input file or flag, an output that could not
    /// be written, an experiment that could not run.
    #[error(transparent)]
    Command(#[from] CommandError),
    /// Arguments clap refused (its first line, and where to find help).
    #[error("{0}")]
    Usage(String),
    /// Standard output failed (a closed pipe is not reported).
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

impl AppError {
    /// An error in option `flag`.
    pub fn flag(flag: &str, message: impl Into<String>) -> AppError {
        CommandError::option(flag, message).into()
    }
}

impl From<FileError> for AppError {
    fn from(e: FileError) -> Self {
        CommandError::File(e).into()
    }
}

impl From<WriteError> for AppError {
    fn from(e: WriteError) -> Self {
        CommandError::Write(e).into()
    }
}

impl From<ExperimentError> for AppError {
    fn from(e: ExperimentError) -> Self {
        CommandError::Experiment(e).into()
    }
}
