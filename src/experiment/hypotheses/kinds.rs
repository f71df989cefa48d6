//! The hypotheses ([`Hypothesis`]) and the parameters each adds ([`Added`]): what the
//! changes are, apart from how a changed filter is built (`build`) and run (`mod.rs`).

use crate::params::ParamDef;

/// A change of a linear filter's model that might explain a misfit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case", tag = "kind", content = "steps")]
pub enum Hypothesis {
    /// The filter built for another time step: F and Q.
    TimeStep,
    /// The filter's initial covariance off by a factor.
    InitialCovariance,
    /// Each measurement component's gain (a scale-factor error).
    SensorGain,
    /// The measurement matrix mixed between components (a misalignment) and scaled.
    MeasurementMatrix,
    /// The measurements read the state this many steps late.
    Delay(usize),
    /// Each measurement component's noise first-order Gauss–Markov, not white.
    ColouredNoise,
    /// A bias on each measurement component, constant or drawn per run.
    SensorBias,
    /// A Gauss–Markov state on each process-noise input (the motion model lacks it).
    MotionState,
    /// Each Q term of the other kind (continuous vs piecewise-constant white noise).
    NoiseKind,
    /// Correlated measurement noise where R was diagonal.
    FullR,
}

impl Hypothesis {
    /// Every hypothesis, in the order trials run.
    pub const ALL: [Hypothesis; 11] = [
        Hypothesis::TimeStep,
        Hypothesis::InitialCovariance,
        Hypothesis::SensorGain,
        Hypothesis::MeasurementMatrix,
        Hypothesis::Delay(1),
        Hypothesis::Delay(2),
        Hypothesis::ColouredNoise,
        Hypothesis::SensorBias,
        Hypothesis::MotionState,
        Hypothesis::NoiseKind,
        Hypothesis::FullR,
    ];

    /// Whether the hypothesis adds states to the filter (judged on its own states).
    pub fn adds_states(self) -> bool {
        matches!(
            self,
            Hypothesis::Delay(_)
                | Hypothesis::ColouredNoise
                | Hypothesis::SensorBias
                | Hypothesis::MotionState
        )
    }

    /// Where the change is: the sensors, the motion model or the start.
    pub fn place(self) -> &'static str {
        match self {
            Hypothesis::TimeStep | Hypothesis::MotionState | Hypothesis::NoiseKind => {
                "the motion model"
            }
            Hypothesis::InitialCovariance => "the start",
            _ => "the sensors",
        }
    }

    /// The hypothesis in a few words.
    pub fn words(self) -> String {
        match self {
            Hypothesis::TimeStep => {
                "the filter's time step (F and Q built for another step)".into()
            }
            Hypothesis::InitialCovariance => "the filter's initial covariance P0".into(),
            Hypothesis::SensorGain => "a sensor's gain (a scale-factor error)".into(),
            Hypothesis::MeasurementMatrix => {
                "the measurement matrix H (a misalignment between components)".into()
            }
            Hypothesis::Delay(d) => format!(
                "a measurement delay of {d} step{}",
                if d == 1 { "" } else { "s" }
            ),
            Hypothesis::ColouredNoise => "coloured (time-correlated) sensor noise".into(),
            Hypothesis::SensorBias => "a sensor bias (constant, or drawn per run)".into(),
            Hypothesis::MotionState => {
                "a state the motion model lacks (a Gauss–Markov acceleration)".into()
            }
            Hypothesis::NoiseKind => {
                "the kind of process noise (continuous vs discrete white noise)".into()
            }
            Hypothesis::FullR => "correlated measurement noise (a full R)".into(),
        }
    }
}

/// One parameter a hypothesis adds, with its neutral value (where the change is no change).
#[derive(Debug, Clone)]
pub struct Added {
    /// The parameter.
    pub def: ParamDef,
    /// Its value where the change is none.
    pub neutral: f64,
    /// For a variance that can only add: the value below which it changes nothing
    /// noticeable (`None`: a factor, neutral within 2% of [`Added::neutral`]).
    pub negligible: Option<f64>,
    /// Whether its value says how large the change is (a rate or a correlation only shapes
    /// a change whose size another parameter gives).
    pub effect: bool,
}

impl Added {
    /// Whether `value` changes nothing.
    pub fn is_neutral(&self, value: f64) -> bool {
        match self.negligible {
            Some(t) => value <= t,
            None => (value / self.neutral).ln().abs() <= 0.02,
        }
    }
}
