//! From a log's sums to its verdict: per sensor the gated NIS average against its single-run
//! interval, the outlier count against its binomial tail, each component's `ν_j²/S_jj` and
//! whiteness, at a family-wise level α (Šidák over every test), and what the evidence
//! blames.

mod summaries;
mod whiteness;

pub use summaries::{Histogram, NisAverage, SensorPlot, WindowSummary};
use summaries::{
    binomial_tail, component_stats, gated_interval, histogram, nis_average, time_warning,
};
pub use whiteness::{CentredWhiteness, MeanTest};
use whiteness::{centred_whiteness, correlation_factor, mean_test, whiteness_stats};

use std::collections::HashMap;

use serde::Serialize;

use crate::fieldlog::analysis::{Dropped, NisAnalyzer, SensorSums};
use crate::fieldlog::settings::Window;
use crate::stats::{
    ComponentStat, Finding, Interval, Suspect, Verdict, WhitenessStat, WhitenessTest, combine,
    gate_alpha, normal_two_sided_quantile, whiteness_tests,
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
    pub px4: Option<super::Px4Channel>,
    /// The estimator parameters the finding points to, with the log's and suggested values
    /// (PX4 logs with a finding on R or Q).
    pub parameters: Vec<super::ParamAdvice>,
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
    pub sources: Vec<super::LogSource>,
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

/// The number of tests a sensor contributes to the family.
fn tests_of(s: &SensorSums, lags: usize) -> usize {
    if s.updates == 0 {
        return 0;
    }
    let m = s.info.components.len();
    let comps = if m > 1 {
        s.comp_n.iter().filter(|n| **n > 0.0).count()
    } else {
        0
    };
    let white = (0..m)
        .filter(|&j| (0..lags).any(|l| s.white_pairs.get(l * m + j).is_some_and(|&p| p >= 1.0)))
        .count();
    let means = s.comp_n.iter().filter(|n| **n >= 2.0).count();
    usize::from(s.gated > 0) + 1 + comps + white + means
}

impl NisAnalyzer {
    /// The report of everything read so far (a log still being written may be reported
    /// again later).
    pub fn report(&self) -> NisReport {
        let alpha = self.settings.alpha();
        let lags = self.settings.lags();
        let gate = self.settings.gate();
        let tests: usize = self.sensors.iter().map(|s| tests_of(s, lags)).sum();
        let level = gate_alpha(alpha, tests);
        let z = normal_two_sided_quantile(alpha);
        let mut sensors: Vec<SensorReport> = Vec::new();
        let mut not_fused = Vec::new();
        // The components' intervals by sample count: computed once each (a chi-square
        // quantile costs microseconds, and a log may have thousands of components).
        let mut intervals: HashMap<u64, Interval> = HashMap::new();
        for s in &self.sensors {
            if s.updates == 0 {
                not_fused.push(NotFused {
                    name: s.info.name.clone(),
                    dropped: s.dropped,
                });
                continue;
            }
            sensors.push(self.sensor_report(s, level, z, &mut intervals));
        }
        crate::fieldlog::advice::attribute(&mut sensors, z);
        let overall = overall(&self.sensors, level);
        let verdict = verdict_of(&sensors);
        let suspect = suspect_of(&sensors);
        NisReport {
            sources: Vec::new(),
            alpha,
            tests,
            test_alpha: level,
            gate,
            window: self.settings.window(),
            lags,
            sensors,
            not_fused,
            overall,
            verdict,
            suspect,
            warnings: self.sensors.iter().filter_map(time_warning).collect(),
        }
    }

    fn sensor_report(
        &self,
        s: &SensorSums,
        level: f64,
        z: f64,
        intervals: &mut HashMap<u64, Interval>,
    ) -> SensorReport {
        let gate = self.settings.gate();
        let lags = self.settings.lags();
        let k = s.updates;
        let m = s.info.components.len();
        let centred: Vec<CentredWhiteness> = (0..m)
            .filter_map(|j| centred_whiteness(s, j, lags, level, z))
            .collect();
        let factor = correlation_factor(s, &centred);
        let n_eff = s.gated as f64 / factor;
        let (nis, inconclusive_reason) = nis_average(s, level, factor, &centred);
        let p_value = binomial_tail(s.outliers, k, gate);
        let outliers_verdict = if p_value < level {
            Verdict::Overconfident
        } else {
            Verdict::Consistent
        };
        let component_stats = if m > 1 {
            component_stats(s, lags, level, &centred, intervals)
        } else {
            Vec::new()
        };
        let whiteness = whiteness_stats(s, lags, z);
        let whiteness_tests = whiteness_tests(&whiteness, &s.info.components, level);
        let mean_tests: Vec<MeanTest> = (0..m)
            .filter_map(|j| mean_test(s, j, lags, level))
            .collect();
        let mut all: Vec<Verdict> = vec![nis.verdict, outliers_verdict];
        all.extend(component_stats.iter().map(|c| c.verdict));
        all.extend(whiteness_tests.iter().map(|w| w.verdict));
        all.extend(mean_tests.iter().map(|t| t.verdict));
        SensorReport {
            name: s.info.name.clone(),
            group: s.info.group.clone(),
            components: s.info.components.clone(),
            updates: k,
            dropped: s.dropped,
            time_span: (s.first_time.unwrap_or(f64::NAN), s.last_time),
            outliers: s.outliers,
            outliers_expected: k as f64 * gate,
            outliers_p_value: p_value,
            outliers_verdict,
            nis,
            nis_mean_all: s.nis_sum_all / k as f64,
            inside_fraction: s.inside as f64 / k as f64,
            window: WindowSummary {
                windows: s.windows,
                outside: s.windows_outside,
                min: s.window_min,
                max: s.window_max,
                last: s.last_window,
            },
            component_stats,
            whiteness,
            whiteness_tests,
            mean_tests,
            centred_whiteness: centred,
            n_eff,
            inconclusive_reason,
            verdict: combine(&all),
            finding: None,
            px4: None,
            parameters: Vec::new(),
            plot: SensorPlot {
                series: s.series.clone(),
                outliers: s.outlier_points.clone(),
                histogram: histogram(s),
            },
        }
    }
}

/// The overall NIS per degree of freedom of every sensor's gated updates, against its
/// interval at `level`.
fn overall(sums: &[SensorSums], level: f64) -> Overall {
    let (mut n, mut o, mut nis, mut dof, mut mean, mut var) = (0, 0, 0.0, 0.0, 0.0, 0.0);
    for s in sums {
        n += s.updates;
        o += s.outliers;
        nis += s.nis_sum;
        dof += s.dof_sum;
        mean += s.mean_sum;
        var += s.var_sum;
    }
    if dof > 0.0 {
        let interval = gated_interval(level, mean, var, dof);
        Overall {
            updates: n,
            outliers: o,
            nis_per_dof: nis / dof,
            target: mean / dof,
            interval,
            level: interval.classify(nis / dof),
        }
    } else {
        let nan = Interval {
            lower: f64::NAN,
            upper: f64::NAN,
        };
        Overall {
            updates: n,
            outliers: o,
            nis_per_dof: f64::NAN,
            target: f64::NAN,
            interval: nan,
            level: Verdict::Inconclusive,
        }
    }
}

/// The log's verdict from its sensors'.
fn verdict_of(sensors: &[SensorReport]) -> Verdict {
    if sensors.is_empty() {
        return Verdict::Inconclusive;
    }
    // A sensor with too few updates for its tests to have power, and nothing failed, says
    // nothing either way: the others decide, unless all are like it.
    let decided: Vec<Verdict> = sensors
        .iter()
        .map(|s| s.verdict)
        .filter(|v| *v != Verdict::Inconclusive)
        .collect();
    if decided.is_empty() {
        Verdict::Inconclusive
    } else {
        combine(&decided)
    }
}

/// What the sensors' findings blame together: a bias first, then Q or R where all that
/// blame one blame the same, Q and R otherwise.
fn suspect_of(sensors: &[SensorReport]) -> Option<Suspect> {
    Suspect::overall(|x| {
        sensors
            .iter()
            .any(|s| s.finding.as_ref().is_some_and(|f| f.suspect == Some(x)))
    })
}
