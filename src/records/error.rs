//! What can be wrong with records: the quantities a file holds do not make a layout, or not
//! the experiment's ([`LayoutError`]); one record is malformed or out of order
//! ([`RecordError`], with a record that does not fit the layout as a [`ShapeError`]). Each
//! renders as one line; the readers put the file, the line or the array in front.
//!
//! Numbers that show a filter broke down are no error in the records: they end the run, and
//! [`Breakdown`] says why.

use std::ops::Range;

use super::MAX_COMPONENTS;
use super::MAX_STEPS;

/// Most degrees of freedom one record's NEES or NIS may claim (and at least 1): they count
/// a filter's state or measurement components. Below 1, the gate's moment-matched
/// chi-square lost its degrees of freedom to underflow (10⁻³⁰⁰ panicked); above, the
/// verdict's quantiles take seconds from about 10¹⁵ total degrees of freedom (N runs times
/// this) and never returned at 10¹⁹, which a mistyped `nees_dof` reached.
pub(super) const MAX_DOF: f64 = 1e6;

/// `x` as an error message shows it: as written for everyday sizes, in exponent form when
/// huge or tiny (`1e300`, not its 301 digits).
pub fn shown_number(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-6..1e16).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// A records file with state quantities for an experiment without them, and the hint.
const NO_GROUND_TRUTH: &str = "state quantities, but the experiment has no ground truth (an [external] problem declares its states, and so its ground truth, in state_names)";

/// `" without components"` where a state or sensor layout has none.
fn without_components(components: bool) -> &'static str {
    if components {
        ""
    } else {
        " without components"
    }
}

/// A sensor as a layout error names it.
fn sensor_label(name: &str) -> String {
    if name.is_empty() {
        "the unnamed sensor".to_string()
    } else {
        format!("sensor '{name}'")
    }
}

/// Why the quantities of a file make no layout, or not the experiment's: what is missing,
/// contradictory, or of a mismatched size (the quantities by their names in the file).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LayoutError {
    /// A quantity with an axis of length 0.
    #[error("{quantity} has shape {shape:?}: no entries")]
    Empty {
        /// The quantity's name.
        quantity: String,
        /// Its dimensions beyond (run, step).
        shape: Vec<usize>,
    },
    /// A quantity with more than [`MAX_COMPONENTS`] components along an axis.
    #[error("{quantity} has shape {shape:?}: above the limit of {MAX_COMPONENTS} components")]
    TooManyComponents {
        /// The quantity's name.
        quantity: String,
        /// Its dimensions beyond (run, step).
        shape: Vec<usize>,
    },
    /// A covariance that is not a square matrix.
    #[error("{quantity} is {shape:?}, not square")]
    NotSquare {
        /// The quantity's name.
        quantity: String,
        /// Its dimensions beyond (run, step).
        shape: Vec<usize>,
    },
    /// Raw and normalized state quantities together.
    #[error("give e and P, or nees, not both")]
    StateBothWays,
    /// The error and the states it is the difference of, together.
    #[error("give e, or x and xhat, not both")]
    ErrorBothWays,
    /// A sensor's raw and normalized quantities together.
    #[error("give {nu} and {s}, or {nis}, not both")]
    SensorBothWays {
        /// Its innovation's name.
        nu: String,
        /// Its covariance's name.
        s: String,
        /// Its NIS's name.
        nis: String,
    },
    /// The truth and the estimate of different sizes.
    #[error("x has {x} entries and xhat {xhat}")]
    StateSizes {
        /// Entries of x.
        x: usize,
        /// Entries of xhat.
        xhat: usize,
    },
    /// A covariance whose side is not its vector's length.
    #[error("{matrix} is {side}×{side} but {vector} has {len} entries")]
    CovarianceSize {
        /// The covariance's name.
        matrix: String,
        /// Its side.
        side: usize,
        /// The vector's name.
        vector: String,
        /// The vector's length.
        len: usize,
    },
    /// A quantity without the one it needs.
    #[error("{given} without {missing}")]
    Without {
        /// What the file has.
        given: String,
        /// What it lacks.
        missing: String,
    },
    /// A NEES or NIS whose degrees of freedom nothing gives.
    #[error("{given} without {missing}: its degrees of freedom are unknown")]
    UnknownDof {
        /// The statistic's name.
        given: String,
        /// What would give its degrees of freedom.
        missing: String,
    },
    /// Nothing to judge.
    #[error("no state or sensor quantities (see docs/src/records.md)")]
    Nothing,
    /// State quantities for an experiment without ground truth.
    #[error("{NO_GROUND_TRUTH}")]
    NoGroundTruth,
    /// No state quantities for an experiment with ground truth.
    #[error("no state quantities (e and P, or nees)")]
    NoState,
    /// A state other than the experiment's.
    #[error(
        "a state of dimension {dim}{}, expected {expected}{}",
        without_components(*.components),
        without_components(*.expected_components)
    )]
    StateDimension {
        /// The file's state dimension.
        dim: usize,
        /// Whether the file gives its components.
        components: bool,
        /// The experiment's.
        expected: usize,
        /// Whether the experiment's records give components.
        expected_components: bool,
    },
    /// A sensor the experiment does not have.
    #[error("{} is not one of the experiment's sensors ({})", sensor_label(.sensor), .known.join(", "))]
    UnknownSensor {
        /// Its name (empty: the unnamed sensor).
        sensor: String,
        /// The experiment's sensors.
        known: Vec<String>,
    },
    /// A sensor of another dimension than the experiment's.
    #[error("{} has dimension {dim}{}, expected {expected}", sensor_label(.sensor), without_components(*.components))]
    SensorDimension {
        /// Its name (empty: the unnamed sensor).
        sensor: String,
        /// Its dimension in the file.
        dim: usize,
        /// Whether the file gives its components.
        components: bool,
        /// The experiment's.
        expected: usize,
    },
}

/// Why one sensor's record does not fit its layout.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SensorShapeError {
    /// ν or S of the wrong size.
    #[error("nu has {nu} entries and S {s}, expected {m} and {m}×{m}")]
    Sizes {
        /// Entries of ν.
        nu: usize,
        /// Entries of S.
        s: usize,
        /// The sensor's dimension.
        m: usize,
    },
    /// Degrees of freedom that do not count components.
    #[error("nis_dof is {}, not a whole number in [1, {MAX_DOF}]", shown_number(*.0))]
    Dof(f64),
    /// `u` at some steps only.
    #[error("u given at some steps and not at others")]
    SometimesU,
    /// `u` of the wrong length.
    #[error("u has {len} entries, expected {m}")]
    ULength {
        /// Its entries.
        len: usize,
        /// The sensor's dimension.
        m: usize,
    },
}

/// Why a record does not fit the layout of the records around it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ShapeError {
    /// State quantities where the layout has none.
    #[error("state quantities in records whose other steps have none")]
    UnexpectedState,
    /// No state quantities where the layout has them.
    #[error("no state quantities (e and P, or nees)")]
    NoState,
    /// e or P of the wrong size.
    #[error("e has {e} entries and P {p}, expected {n} and {n}×{n}")]
    StateSizes {
        /// Entries of e.
        e: usize,
        /// Entries of P.
        p: usize,
        /// The state's dimension.
        n: usize,
    },
    /// Degrees of freedom that do not count components.
    #[error("nees_dof is {}, not a whole number in [1, {MAX_DOF}]", shown_number(*.0))]
    NeesDof(f64),
    /// `e2p` at some steps only.
    #[error("e2p given at some steps and not at others")]
    SometimesE2p,
    /// `e2p` of the wrong length.
    #[error("e2p has {len} entries, expected {n}")]
    E2pLength {
        /// Its entries.
        len: usize,
        /// The state's dimension.
        n: usize,
    },
    /// A sensor index the layout does not have.
    #[error("sensor index {0} out of range")]
    SensorIndex(usize),
    /// One sensor's record.
    #[error("{}: {problem}", if .sensor.is_empty() { "the sensor".to_string() } else { format!("sensor {}", .sensor) })]
    Sensor {
        /// Its name (empty: the unnamed sensor).
        sensor: String,
        /// What is wrong.
        problem: SensorShapeError,
    },
}

/// Why a record, or the records of an experiment together, cannot be read into its sums:
/// a malformed line or cell, a record that does not fit the layout, runs or steps out of
/// order or missing.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RecordError {
    /// A line that is not JSON (the parser's words).
    #[error("not JSON: {0}")]
    NotJson(String),
    /// JSON other than an object.
    #[error("not a JSON object")]
    NotObject,
    /// A record without its run or step.
    #[error("no '{0}'")]
    NoIndex(&'static str),
    /// A run or step that is not a count.
    #[error("{key}: {value} is not a non-negative integer")]
    BadIndex {
        /// `run` or `step`.
        key: &'static str,
        /// The value as written.
        value: String,
    },
    /// Step 0.
    #[error("step: 0 (steps count from 1)")]
    StepZero,
    /// A step beyond [`MAX_STEPS`].
    #[error("step: {0} is above the limit of {MAX_STEPS} steps per run")]
    StepAboveLimit(usize),
    /// A key that names no quantity.
    #[error("unknown key '{0}' (see docs/src/records.md for the names)")]
    UnknownKey(String),
    /// A value that is no number, list or matrix.
    #[error("{0}: not a number, a list of numbers, or a list of rows")]
    NotNumbers(String),
    /// A matrix whose rows differ in length.
    #[error("{0}: rows of different lengths")]
    RaggedRows(String),
    /// A flat matrix whose count is not a square.
    #[error("{key}: {count} numbers, not a square matrix")]
    NotSquareCount {
        /// The quantity.
        key: String,
        /// Its numbers.
        count: usize,
    },
    /// A number, list or matrix where another is expected.
    #[error("{key}: {given} where a {expected} is expected")]
    WrongRank {
        /// The quantity.
        key: String,
        /// What was given: "a number", "a list", "a matrix".
        given: &'static str,
        /// What was expected: "number", "list", "matrix".
        expected: &'static str,
    },
    /// A quantity of a sensor the experiment does not have.
    #[error("{quantity}: '{sensor}' is not one of the experiment's sensors ({})", .known.join(", "))]
    UnknownSensor {
        /// The quantity.
        quantity: String,
        /// The sensor it names.
        sensor: String,
        /// The experiment's sensors.
        known: Vec<String>,
    },
    /// A state quantity for an experiment without ground truth.
    #[error("{0}: {NO_GROUND_TRUTH}")]
    NoGroundTruth(String),
    /// A cell that is not a number.
    #[error("{column}: '{cell}' is not a number")]
    NotANumber {
        /// The column.
        column: String,
        /// The cell, as an error quotes it.
        cell: String,
    },
    /// Quantities that make no layout.
    #[error(transparent)]
    Layout(#[from] LayoutError),
    /// A run not in the range asked for.
    #[error("run {run} was not asked for (runs {}..{})", .asked.start, .asked.end)]
    NotAskedFor {
        /// The run.
        run: usize,
        /// The runs asked for.
        asked: Range<usize>,
    },
    /// A run whose records are not together.
    #[error("run {0} appears twice (a run's records must come together)")]
    RunTwice(usize),
    /// A step that does not follow the last.
    #[error("run {run}: step {step} follows step {last} (steps go 1, 2, …, {steps} without gaps)")]
    StepGap {
        /// The run.
        run: usize,
        /// Its step.
        step: usize,
        /// The step before.
        last: usize,
        /// Steps per run T.
        steps: usize,
    },
    /// A step beyond the experiment's.
    #[error("run {run}: step {step} beyond the {steps} steps of the experiment")]
    StepBeyond {
        /// The run.
        run: usize,
        /// Its step.
        step: usize,
        /// Steps per run T.
        steps: usize,
    },
    /// A run that stops early without being marked diverged.
    #[error("run {run}: ends at step {last} of {steps} without being marked diverged")]
    EndsEarly {
        /// The run.
        run: usize,
        /// Its last step.
        last: usize,
        /// Steps per run T.
        steps: usize,
    },
    /// Runs asked for that did not come.
    #[error("{came} of the {} runs asked for ({}..{}) came back; run {missing} is missing", .asked.len(), .asked.start, .asked.end)]
    RunsMissing {
        /// Runs that came.
        came: usize,
        /// The runs asked for.
        asked: Range<usize>,
        /// The first missing.
        missing: usize,
    },
    /// No run at all.
    #[error("no runs")]
    NoRuns,
    /// A record that does not fit the layout.
    #[error("run {run}, step {step}: {problem}")]
    Shape {
        /// Its run.
        run: usize,
        /// Its step.
        step: usize,
        /// What does not fit.
        problem: ShapeError,
    },
}

/// Numbers of a step that show its filter broke down: the run stops there, and this is
/// the reason the sums keep.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Breakdown {
    /// Values that are not finite (`"nu or S"`, `"u"`, `"e or P"`).
    #[error("{0} is not finite")]
    NotFinite(&'static str),
    /// A covariance that is not positive definite (`"S"`, `"P"`).
    #[error("{0} is not positive definite")]
    NotPositiveDefinite(&'static str),
    /// A statistic that overflowed (`"NIS"`, `"NEES"`).
    #[error("the {0} overflowed")]
    Overflowed(&'static str),
    /// A precomputed statistic that is negative or not finite (`"NIS"`, `"NEES or e2p"`).
    #[error("the {0} is negative or not finite")]
    NegativeOrNotFinite(&'static str),
}
