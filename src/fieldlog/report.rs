//! From a log's sums to its verdict: per sensor the gated NIS average against its single-run
//! interval, the outlier count against its binomial tail, each component's `ν_j²/S_jj` and
//! whiteness, at a family-wise level α (Šidák over every test), and what the evidence
//! blames.

use std::collections::HashMap;

use serde::Serialize;
use statrs::function::beta::beta_reg;

use super::analysis::{Dropped, HIST_BINS, NisAnalyzer, SensorSums, SeriesPoint};
use super::settings::Window;
use crate::stats::{
    ComponentStat, Finding, Interval, Suspect, Verdict, WhitenessStat, WhitenessTest,
    chi2_average_interval, combine, gate_alpha, has_power, normal_two_sided_quantile,
    scaled_chi2_interval, whiteness_tests,
};

/// A gated NIS average and its test.
#[derive(Debug, Clone, Serialize)]
pub struct NisAverage {
    /// Average NIS over the updates inside the outlier gate.
    pub mean: f64,
    /// What a consistent filter's gated average is (its dimension, less the tail the gate
    /// cuts off).
    pub target: f64,
    /// Single-run interval at the test level: the sum of K truncated `χ²(m)` variables,
    /// moment-matched (exactly `χ²(K m)/K` without the gate).
    pub interval: Interval,
    /// Degrees of freedom summed over the gated updates.
    pub dof: f64,
    /// Where the average falls ([`Verdict::Inconclusive`] when inside but the test could
    /// not tell a factor-2 error).
    pub verdict: Verdict,
}

/// The moving-window average over a sensor's log.
#[derive(Debug, Clone, Serialize)]
pub struct WindowSummary {
    /// Windows evaluated (one per gated update once the window has filled).
    pub windows: usize,
    /// Of those, outside their interval at α (each window's own `χ²` interval); about α of
    /// them for a consistent filter, in runs, since windows overlap.
    pub outside: usize,
    /// The lowest window average and its time (s).
    pub min: Option<(f64, f64)>,
    /// The highest window average and its time (s).
    pub max: Option<(f64, f64)>,
    /// The latest window's average and interval.
    pub last: Option<(f64, f64, f64)>,
}

/// A histogram of one dimension's NIS values, for the plot against the χ² density.
#[derive(Debug, Clone, Serialize)]
pub struct Histogram {
    /// The measurement dimension m.
    pub dof: usize,
    /// Upper end of the bins, `χ²⁻¹(0.999, m)`; bins are equal over `[0, top]`.
    pub top: f64,
    /// Counts per bin.
    pub counts: Vec<u64>,
    /// Values above `top`.
    pub above: u64,
}

/// What a sensor's report needs for its plots (not in the JSON).
#[derive(Debug, Clone, Default)]
pub struct SensorPlot {
    /// NIS and the window average over time, decimated to a few thousand points.
    pub series: Vec<SeriesPoint>,
    /// Outliers (time s, NIS), the first thousand.
    pub outliers: Vec<(f64, f64)>,
    /// The histogram of the most common dimension.
    pub histogram: Option<Histogram>,
}

/// The zero-mean test of one component's normalized innovations `u = ν_j/√S_jj` over a
/// log: a filter that models its sensor's bias has innovations of mean 0.
///
/// The updates of one log are one run, correlated in time when the filter is not optimal,
/// so the mean's variance is `(1/n)(1 + 2 Σ_{l=1}^{L} (1 − l/n) ρ_l)` and the test uses the
/// effective sample size `n_eff = n / (1 + 2 Σ_l (1 − l/n) ρ_l)` (Bartlett's formula; the
/// lags and lagged sums are the whiteness statistics', `ρ_l` centred on the mean), clamped
/// to `[1, n]`:
/// `z = ū √n_eff / s`, with `s²` the variance of u about its mean floored at 1 (never
/// narrower than a consistent filter's, so an S that is too small is left to the
/// second-moment tests), two-sided against Student's t with `n_eff − 1` degrees of freedom.
#[derive(Debug, Clone, Serialize)]
pub struct MeanTest {
    /// Component name.
    pub component: String,
    /// Updates inside the outlier gate behind the mean.
    pub samples: f64,
    /// `ū`, in standard deviations of the filter's S.
    pub mean: f64,
    /// The share of `E[u²]` the mean carries, `ū² / mean(u²)`: near 1 when the innovations
    /// are mostly an offset (large even where the test cannot be significant).
    pub mean_share: f64,
    /// The effective sample size after the autocorrelation correction.
    pub n_eff: f64,
    /// The test statistic.
    pub z: f64,
    /// Its two-sided threshold at the test level.
    pub threshold: f64,
    /// [`Verdict::Biased`] beyond the threshold, else consistent.
    pub verdict: Verdict,
}

/// The autocorrelation of component `j` of sensor `s` at lag `l`, centred on the
/// component's mean over the gated updates, and its pairs; `None` without pairs. Centred,
/// a bias does not read as correlation: raw, it adds `b²/(1 + b²)` to every lag's ρ.
fn centred_rho(s: &SensorSums, l: usize, j: usize) -> Option<(f64, f64)> {
    let m = s.info.components.len();
    let n = s.comp_n[j];
    let idx = (l - 1) * m + j;
    let pairs = s.white_pairs.get(idx).copied().unwrap_or(0.0);
    if pairs < 1.0 || n < 1.0 {
        return None;
    }
    let mean = s.comp_mean_sum[j] / n;
    let c = |x: f64| x / pairs - mean * mean;
    let den = (c(s.white_a2[idx]) * c(s.white_b2[idx])).sqrt();
    let rho = if den > 0.0 {
        c(s.white_ab[idx]) / den
    } else {
        0.0
    };
    Some((rho, pairs))
}

/// The part of `2 Σ_l (1 − l/n) r_l` past the last lag `l_max` measured, for a correlation
/// `r_last` there that goes on decaying like an AR(1) of lag-1 correlation `rho1`: 0 unless
/// both are positive. At ρ₁ = 0.98 the first ten lags hold only a fifth of the sum, and a
/// truncated sum would count five times the independent samples there are.
fn ar1_tail(l_max: usize, r_last: f64, rho1: f64, n: f64) -> f64 {
    if !(rho1 > 0.0 && rho1 < 1.0 && r_last > 0.0) {
        return 0.0;
    }
    let (mut tail, mut r) = (0.0, r_last);
    for l in l_max + 1..(n as usize) {
        r *= rho1;
        if r < 1e-4 {
            break;
        }
        tail += 2.0 * (1.0 - l as f64 / n) * r;
    }
    tail
}

/// The zero-mean test of component `j` of sensor `s` at `level` (see [`MeanTest`]).
fn mean_test(s: &SensorSums, j: usize, lags: usize, level: f64) -> Option<MeanTest> {
    let n = s.comp_n[j];
    if n < 2.0 {
        return None;
    }
    let mean = s.comp_mean_sum[j] / n;
    let mut factor = 1.0;
    let mut last = None;
    for l in 1..=lags {
        let Some((rho, _)) = centred_rho(s, l, j) else {
            continue;
        };
        factor += 2.0 * (1.0 - l as f64 / n).max(0.0) * rho;
        last = Some((l, rho));
    }
    if let (Some((l_max, r_last)), Some((rho1, _))) = (last, centred_rho(s, 1, j)) {
        factor += ar1_tail(l_max, r_last, rho1, n);
    }
    let n_eff = if factor > 0.0 { n / factor } else { n }.clamp(1.0, n);
    let second = s.comp_sum[j] / n;
    let sd = (second - mean * mean).max(1.0).sqrt();
    let z = mean * n_eff.sqrt() / sd;
    let threshold = statrs::distribution::StudentsT::new(0.0, 1.0, (n_eff - 1.0).max(1.0))
        .map(|d| {
            use statrs::distribution::ContinuousCDF;
            d.inverse_cdf(1.0 - level / 2.0)
        })
        .unwrap_or(f64::INFINITY);
    Some(MeanTest {
        component: s.info.components[j].clone(),
        samples: n,
        mean,
        mean_share: if second > 0.0 {
            (mean * mean / second).min(1.0)
        } else {
            0.0
        },
        n_eff,
        z,
        threshold,
        verdict: if z.abs() > threshold {
            Verdict::Biased
        } else {
            Verdict::Consistent
        },
    })
}

/// The whiteness of one component's innovations centred on their mean: what the decisions
/// read (the gain's sign in the advice, the effective sample size), while the reported
/// [`WhitenessStat`]s stay raw, as a white filter's are defined.
#[derive(Debug, Clone, Serialize)]
pub struct CentredWhiteness {
    /// Component name.
    pub component: String,
    /// Centred lag-1 autocorrelation.
    pub rho1: f64,
    /// Its band at α for a white sequence, `z_{1−α/2}/√pairs`.
    pub band: f64,
    /// Lag-1 pairs.
    pub pairs: f64,
    /// The centred portmanteau `Σ_l pairs_l ρ_l²` over the lags with pairs.
    pub statistic: f64,
    /// Its threshold at the test level.
    pub threshold: f64,
    /// Whether the portmanteau rejects whiteness at the test level.
    pub not_white: bool,
    /// The variance factor of the average of `u²` over the log,
    /// `1 + 2 Σ_l (1 − l/n) ρ²_l` with `ρ²_l` the lag-l correlation of u² (for Gaussian u
    /// of mean b and variance σ², `(2σ²ρ_l² + 4b²ρ_l)/(2σ² + 4b²)`), continued past the last
    /// lag as an AR(1) with the lag-1 ρ;
    /// 1 where the portmanteau does not reject, so a white log's intervals stay exact.
    pub square_factor: f64,
}

/// The centred whiteness of component `j` of `s` over `lags` at `level`, with `z` the
/// band's quantile; `None` without lag-1 pairs.
fn centred_whiteness(
    s: &SensorSums,
    j: usize,
    lags: usize,
    level: f64,
    z: f64,
) -> Option<CentredWhiteness> {
    let (rho1, pairs) = centred_rho(s, 1, j)?;
    let n = s.comp_n[j];
    // For Gaussian u of mean b and variance σ², the lag-l correlation of u² is
    // (2σ²ρ_l² + 4b²ρ_l) / (2σ² + 4b²): ρ_l² without a bias, but ρ_l itself when the bias
    // dominates (then the NIS average moves with the slow wander of u, not its square).
    let b = s.comp_mean_sum[j] / n;
    let var = (s.comp_sum[j] / n - b * b).max(f64::MIN_POSITIVE);
    let square_rho =
        |rho: f64| (2.0 * var * rho * rho + 4.0 * b * b * rho) / (2.0 * var + 4.0 * b * b);
    let (mut statistic, mut dof, mut factor) = (0.0, 0usize, 1.0);
    let mut last = None;
    for l in 1..=lags {
        let Some((rho, p)) = centred_rho(s, l, j) else {
            continue;
        };
        statistic += p * rho * rho;
        dof += 1;
        factor += 2.0 * (1.0 - l as f64 / n).max(0.0) * square_rho(rho);
        last = Some((l, square_rho(rho)));
    }
    // Past the last lag, a correlation that decays like the lag-1 one's (an AR(1) tail):
    // at ρ₁ = 0.98 the lags up to 10 hold only a fifth of the sum.
    if let Some((l_max, r_last)) = last {
        factor += ar1_tail(l_max, r_last, rho1, n);
    }
    let threshold = crate::stats::chi2_inv(1.0 - level, dof as f64);
    let not_white = statistic > threshold;
    Some(CentredWhiteness {
        component: s.info.components[j].clone(),
        rho1,
        band: z / pairs.sqrt(),
        pairs,
        statistic,
        threshold,
        not_white,
        square_factor: if not_white { factor } else { 1.0 },
    })
}

/// `n_eff` in words: a whole number below 10, else two significant digits.
fn about(n: f64) -> String {
    if n < 10.0 {
        format!("{:.0}", n.max(1.0))
    } else {
        let mag = 10f64.powi(n.log10().floor() as i32 - 1);
        format!("{:.0}", (n / mag).round() * mag)
    }
}

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

/// The interval of `sum / count` for a sum of gated χ² variables with the given mean and
/// variance.
fn gated_interval(level: f64, mean: f64, var: f64, count: f64) -> Interval {
    if var > 0.0 {
        scaled_chi2_interval(level, mean, var, count).0
    } else {
        Interval {
            lower: mean / count,
            upper: mean / count,
        }
    }
}

/// What a sensor's time stamps put in doubt, in one line: all one time (zero or not), or
/// updates that do not come after the one before.
fn time_warning(s: &SensorSums) -> Option<String> {
    let n = s.updates;
    if n < 2 {
        return None;
    }
    let name = &s.info.name;
    if s.time_min == s.time_max {
        let t = s.time_min;
        return Some(format!(
            "{name}: all {n} updates have time {}: the time axis and time windows are meaningless",
            if t == 0.0 {
                "0".to_string()
            } else {
                super::advice::short(t)
            }
        ));
    }
    (s.non_increasing > 0).then(|| {
        format!(
            "{name}: {} of {n} updates do not come after the one before (equal or earlier time): the time axis and time windows are unreliable",
            s.non_increasing
        )
    })
}

/// `P(X ≥ k)` for `X ~ Binomial(n, p)`.
fn binomial_tail(k: usize, n: usize, p: f64) -> f64 {
    if k == 0 {
        1.0
    } else if k > n {
        0.0
    } else {
        beta_reg(k as f64, (n - k + 1) as f64, p)
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
        super::advice::attribute(&mut sensors, z);
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

/// The factor by which strongly correlated innovations inflate the variance of the NIS
/// average: they carry fewer independent samples than updates, so the average's variance
/// grows by the components' mean factor (independent components add their sums'
/// variances).
fn correlation_factor(s: &SensorSums, centred: &[CentredWhiteness]) -> f64 {
    let m = s.info.components.len();
    let f: Vec<f64> = (0..m)
        .filter(|&j| s.comp_n[j] > 0.0)
        .map(|j| {
            centred
                .iter()
                .find(|c| c.component == s.info.components[j])
                .map_or(1.0, |c| c.square_factor)
        })
        .collect();
    if f.is_empty() {
        1.0
    } else {
        f.iter().sum::<f64>() / f.len() as f64
    }
}

/// The gated NIS average against its interval at `level` (widened by the correlation
/// `factor`), and why it is inconclusive when too few independent samples remain.
fn nis_average(
    s: &SensorSums,
    level: f64,
    factor: f64,
    centred: &[CentredWhiteness],
) -> (NisAverage, Option<String>) {
    if s.gated == 0 {
        let nan = NisAverage {
            mean: f64::NAN,
            target: f64::NAN,
            interval: Interval {
                lower: f64::NAN,
                upper: f64::NAN,
            },
            dof: 0.0,
            verdict: Verdict::Inconclusive,
        };
        return (nan, None);
    }
    let mut inconclusive_reason = None;
    let count = s.gated as f64;
    let interval = gated_interval(level, s.mean_sum, s.var_sum * factor, count);
    let mean = s.nis_sum / count;
    let mut verdict = interval.classify(mean);
    let powered = has_power(level, s.dof_sum / factor);
    if factor > 1.0 && !powered {
        let worst = centred
            .iter()
            .max_by(|a, b| a.square_factor.total_cmp(&b.square_factor));
        inconclusive_reason = Some(format!(
            "not enough independent samples to judge: about {} of {}{}",
            about(s.gated as f64 / factor),
            s.gated,
            worst.map_or(String::new(), |w| format!(" (ρ₁ = {:+.2})", w.rho1))
        ));
        verdict = Verdict::Inconclusive;
    } else if verdict == Verdict::Consistent && !powered {
        verdict = Verdict::Inconclusive;
    }
    let average = NisAverage {
        mean,
        target: s.mean_sum / count,
        interval,
        dof: s.dof_sum,
        verdict,
    };
    (average, inconclusive_reason)
}

/// Each measured component's average of `u²` against its interval at `level` (widened by
/// its correlation factor), with its mean test. `intervals` caches the intervals by sample
/// count: a chi-square quantile costs microseconds, and a log may have thousands of
/// components.
fn component_stats(
    s: &SensorSums,
    lags: usize,
    level: f64,
    centred: &[CentredWhiteness],
    intervals: &mut HashMap<u64, Interval>,
) -> Vec<ComponentStat> {
    (0..s.info.components.len())
        .filter(|&j| s.comp_n[j] > 0.0)
        .map(|j| {
            let n = s.comp_n[j];
            let f = centred
                .iter()
                .find(|c| c.component == s.info.components[j])
                .map_or(1.0, |c| c.square_factor);
            // The average of n u² with variance factor f is χ²(n/f)/(n/f).
            let interval = if f > 1.0 {
                chi2_average_interval(level, n / f, n / f)
            } else {
                *intervals
                    .entry(n.to_bits())
                    .or_insert_with(|| chi2_average_interval(level, n, n))
            };
            let value = s.comp_sum[j] / n;
            let verdict = if f > 1.0 && !has_power(level, n / f) {
                Verdict::Inconclusive
            } else {
                interval.classify(value)
            };
            let mt = mean_test(s, j, lags, level);
            ComponentStat {
                mean: s.comp_mean_sum[j] / n,
                mean_z: mt.as_ref().map_or(f64::NAN, |t| t.z),
                mean_verdict: mt.as_ref().map_or(Verdict::Inconclusive, |t| t.verdict),
                name: s.info.components[j].clone(),
                kind: "measurement",
                value,
                interval,
                samples: n,
                verdict,
            }
        })
        .collect()
}

/// The lagged autocorrelations of each component, lag by lag, with their bands `z/√pairs`.
fn whiteness_stats(s: &SensorSums, lags: usize, z: f64) -> Vec<WhitenessStat> {
    let m = s.info.components.len();
    let mut whiteness = Vec::new();
    for lag in 1..=lags {
        for j in 0..m {
            let idx = (lag - 1) * m + j;
            let pairs = s.white_pairs.get(idx).copied().unwrap_or(0.0);
            if pairs < 1.0 {
                continue;
            }
            let den = (s.white_a2[idx] * s.white_b2[idx]).sqrt();
            whiteness.push(WhitenessStat {
                component: s.info.components[j].clone(),
                lag,
                rho: if den > 0.0 {
                    s.white_ab[idx] / den
                } else {
                    0.0
                },
                band: z / pairs.sqrt(),
                pairs,
            });
        }
    }
    whiteness
}

/// The histogram of the NIS of the degrees of freedom with the most updates.
fn histogram(s: &SensorSums) -> Option<Histogram> {
    let histogram = s
        .hist
        .iter()
        .max_by_key(|h| h.1.iter().sum::<u64>() + h.2)
        .map(|(dof, counts, above)| Histogram {
            dof: *dof,
            top: crate::stats::chi2_inv(0.999, *dof as f64),
            counts: counts.clone(),
            above: *above,
        });
    debug_assert!(
        histogram
            .as_ref()
            .is_none_or(|h| h.counts.len() == HIST_BINS)
    );
    histogram
}
