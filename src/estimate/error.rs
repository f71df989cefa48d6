//! Why Q and R could not be estimated from a record: the record does not suit the method,
//! the filter at the start values cannot be used, the unknowns are not identified, or a
//! solver failed. Each renders as one line; the command line puts the record's name in
//! front.

/// Why an estimate could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EstimateError {
    /// ALS on a record with gaps.
    #[error(
        "ALS needs every component measured at every step (use --method ml for records with gaps)"
    )]
    Gaps,
    /// The innovation covariance at the start values has no inverse.
    #[error("S is singular at the start values")]
    SingularS,
    /// The Riccati recursion at the start values does not settle.
    #[error("the filter's covariance does not settle at the start values")]
    NotSettling,
    /// The fixed-gain filter at the start values is unstable.
    #[error(
        "the filter at the start values is unstable (spectral radius of F(I − KH) is {0:.4}): ALS needs a stable filter"
    )]
    Unstable(f64),
    /// Too few innovations for the lags asked for.
    #[error(
        "the record is too short for {lags} lags: {samples} innovations after dropping the first {burn} steps of each sequence (the filter's transient)"
    )]
    TooShort {
        /// Lags asked for.
        lags: usize,
        /// Innovations after the transient.
        samples: usize,
        /// Steps dropped from each sequence.
        burn: usize,
    },
    /// Every parameter fixed.
    #[error("there is nothing to estimate: every parameter is fixed")]
    NothingToEstimate,
    /// Unknowns the autocovariances do not determine (`what` names them, with its verb).
    #[error(
        "{what} not identified by these autocovariances: {unknowns} unknowns in all, only {rank} independent (fewer free parameters or noise inputs, more lags)"
    )]
    NotIdentified {
        /// The unknowns, as the message names them ("the parameters are").
        what: String,
        /// Unknowns.
        unknowns: usize,
        /// Independent columns.
        rank: usize,
    },
    /// A full Q asked for where Q has no noise inputs.
    #[error("the problem's Q has no noise inputs to estimate a covariance of")]
    NoNoiseInputs,
    /// The conic solver refused the problem (its words).
    #[error("the least-squares problem could not be set up: {0}")]
    SolverSetup(String),
    /// The conic solver stopped without a solution (its status).
    #[error("the constrained least squares did not solve: {0}")]
    NotSolved(String),
    /// The semidefinite solver's answer is indefinite beyond its tolerance.
    #[error(
        "the semidefinite solver returned an indefinite {what} (smallest eigenvalue {smallest:e})"
    )]
    Indefinite {
        /// The matrix ("Q", "R").
        what: String,
        /// Its smallest eigenvalue.
        smallest: f64,
    },
    /// The likelihood cannot be evaluated at the start values.
    #[error("the likelihood is not defined at the start values (S is not positive definite)")]
    UndefinedAtStart,
    /// The likelihood search stopped with an error (its words).
    #[error("the likelihood search failed: {0}")]
    SearchFailed(String),
}

/// Why a likelihood could not be evaluated: the innovation covariance lost definiteness.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("S is not positive definite at step {step}")]
pub struct NotDefinite {
    /// The step (1-based).
    pub step: usize,
}
