//! What `autotune nis` says: about each sensor ([`SensorReport`]), the sensors that were
//! logged but not fused ([`NotFused`]), all updates together ([`Overall`]), and the whole
//! log ([`NisReport`]).

use serde::Serialize;

use super::summaries::{NisAverage, SensorPlot, WindowSummary};
use super::whiteness::{CentredWhiteness, MeanTest};
use crate::fieldlog::analysis::Dropped;
use crate::fieldlog::px4::{ParamAdvice, Px4Channel};
use crate::fieldlog::settings::Window;
use crate::fieldlog::source::LogSource;
use crate::stats::{
    ComponentStat, Finding, Interval, Suspect, Verdict, WhitenessStat, WhitenessTest,
};

/// Everything `autotune nis` says about one sensor.
#[derive(Debug, Clone, Serialize)]
pub struct SensorReport {
    /// Name.
    pub name: String,
    /// The estimator it belongs to (empty for a single filter).
    pub group: String,
    /// Component names (empty when the log gives the NIS alone).
    pub components: Vec<String>,
    /// Updates read (outliers included).
    pub updates: usize,
    /// Rows the reader dropped before the statistics.
    pub dropped: Dropped,
    /// Time of the first and the last update, seconds.
    pub time_span: (f64, f64),
    /// Updates whose NIS is beyond the outlier gate: counted, not averaged.
    pub outliers: usize,
    /// How many a consistent filter would have, `K · p`.
    pub outliers_expected: f64,
    /// `P(X ≥ outliers)` for `X ~ Binomial(K, p)`.
    pub outliers_p_value: f64,
    /// [`Verdict::Overconfident`] when that is below the test level: the tails are heavier
    /// than S allows.
    pub outliers_verdict: Verdict,
    /// The gated average NIS and its test.
    pub nis: NisAverage,
    /// Average NIS over every update, outliers included.
    pub nis_mean_all: f64,
    /// Fraction of updates whose NIS lies in its own two-sided interval at α; about 1 − α
    /// for a consistent filter.
    pub inside_fraction: f64,
    /// The moving window.
    pub window: WindowSummary,
    /// `ν_j²/S_jj` per component (sensors of two or more components).
    pub component_stats: Vec<ComponentStat>,
    /// Normalized autocorrelation of each component's innovations at lags 1..L, on the
    /// sensor's own update sequence, with the band of a white sequence at α.
    pub whiteness: Vec<WhitenessStat>,
    /// The portmanteau test of each component over the lags, at the test level.
    pub whiteness_tests: Vec<WhitenessTest>,
    /// The zero-mean test of each component (a log with components), at the test level.
    pub mean_tests: Vec<MeanTest>,
    /// Each component's whiteness centred on its mean: what the advice and the effective
    /// sample size read.
    pub centred_whiteness: Vec<CentredWhiteness>,
    /// Effective number of independent updates behind the gated NIS average: the gated
    /// updates divided by the mean of the components' [`CentredWhiteness::square_factor`]
    /// (the gated count itself when every component is white).
    pub n_eff: f64,
    /// Why the NIS average's test could not judge the sensor, when it could not (too few
    /// independent samples: strongly correlated innovations).
    pub inconclusive_reason: Option<String>,
    /// The sensor's verdict (all its tests).
    pub verdict: Verdict,
    /// What the evidence blames, when the sensor fails.
    pub finding: Option<Finding>,
    /// What a PX4 EKF says about the channel beside its innovations (PX4 logs only).
    pub px4: Option<Px4Channel>,
    /// The estimator parameters the finding points to, with the log's and suggested values
    /// (PX4 logs with a finding on R or Q).
    pub parameters: Vec<ParamAdvice>,
    /// Data for the plots.
    #[serde(skip)]
    pub plot: SensorPlot,
}

/// A channel the log carries that was never fused.
#[derive(Debug, Clone, Serialize)]
pub struct NotFused {
    /// Name.
    pub name: String,
    /// Its rows, by why they were dropped.
    pub dropped: Dropped,
}

/// All sensors pooled: NIS per degree of freedom.
#[derive(Debug, Clone, Serialize)]
pub struct Overall {
    /// Updates of all sensors.
    pub updates: usize,
    /// Outliers of all sensors.
    pub outliers: usize,
    /// `Σ NIS / Σ m` over the gated updates.
    pub nis_per_dof: f64,
    /// Its value for a consistent filter (1 less the gate's tail).
    pub target: f64,
    /// Its single-run interval at the test level.
    pub interval: Interval,
    /// Where the pooled average falls (context: the gate's verdict combines the sensors).
    pub level: Verdict,
}

/// Everything `autotune nis` reports about a log.
#[derive(Debug, Clone, Serialize)]
pub struct NisReport {
    /// The files read and what their readers noted.
    pub sources: Vec<LogSource>,
    /// Family-wise significance level α.
    pub alpha: f64,
    /// How many tests the verdict applies.
    pub tests: usize,
    /// The level of each, `1 − (1 − α)^{1/tests}` (Šidák).
    pub test_alpha: f64,
    /// Tail probability of the outlier gate.
    pub gate: f64,
    /// The moving window.
    pub window: Window,
    /// Whiteness lags.
    pub lags: usize,
    /// The sensors with updates.
    pub sensors: Vec<SensorReport>,
    /// Channels the log carries that had no update.
    pub not_fused: Vec<NotFused>,
    /// All sensors pooled.
    pub overall: Overall,
    /// The verdict of every test together.
    pub verdict: Verdict,
    /// What the failing sensors' evidence points to overall.
    pub suspect: Option<Suspect>,
    /// What the data themselves put in doubt (time stamps that do not increase, ...), one
    /// line each.
    pub warnings: Vec<String>,
}

impl NisReport {
    /// One line: what the evidence points to, or `None` when nothing is off.
    pub fn headline(&self) -> Option<String> {
        self.suspect
            .map(|s| format!("the evidence points to {}", s.words()))
    }
}
