//! From a log's sums to its verdict: per sensor the gated NIS average against its single-run
//! interval, the outlier count against its binomial tail, each component's `ν_j²/S_jj` and
//! whiteness, at a family-wise level α (Šidák over every test), and what the evidence
//! blames.

mod sensor;
mod summaries;
mod whiteness;

pub use sensor::{NisReport, NotFused, Overall, SensorReport};
pub(in crate::fieldlog) use summaries::short;
pub use summaries::{Histogram, NisAverage, SensorPlot, WindowSummary};
use summaries::{
    binomial_tail, component_stats, gated_interval, histogram, nis_average, time_warning,
};
pub use whiteness::{CentredWhiteness, MeanTest};
use whiteness::{centred_whiteness, correlation_factor, mean_test, whiteness_stats};

use std::collections::HashMap;

use crate::fieldlog::analysis::{NisAnalyzer, SensorSums};
use crate::stats::{
    Interval, Suspect, Verdict, combine, gate_alpha, normal_two_sided_quantile, whiteness_tests,
};

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
