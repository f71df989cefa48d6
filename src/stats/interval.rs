//! Chi-square acceptance intervals, the power check, and verdicts.
//!
//! Over N independent runs, `N · ANEES_k ~ χ²(N n_x)` under a consistent filter, so its
//! two-sided (1 − α) acceptance interval is `[χ²⁻¹(α/2, N n_x)/N, χ²⁻¹(1 − α/2, N n_x)/N]`
//! (Bar-Shalom, Li, Kirubarajan 2001, §5.4); sums with correlated terms use a moment-matched
//! scaled chi-square (Satterthwaite 1946).

use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF, Normal, StudentsT};

/// Inverse of the chi-square CDF: the `p` quantile of `χ²(dof)`.
///
/// `dof` may be fractional (for moment-matched approximations). Panics only if `dof` is
/// not positive and finite, which callers rule out.
pub fn chi2_inv(p: f64, dof: f64) -> f64 {
    ChiSquared::new(dof)
        .expect("chi-square degrees of freedom must be positive and finite")
        .inverse_cdf(p)
}

/// A closed acceptance interval `[lower, upper]` for an averaged statistic.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Interval {
    /// Lower bound `r1`.
    pub lower: f64,
    /// Upper bound `r2`.
    pub upper: f64,
}

impl Interval {
    /// Whether `v` lies inside the interval (bounds included).
    pub fn contains(&self, v: f64) -> bool {
        v >= self.lower && v <= self.upper
    }

    /// Where `v` lies relative to the interval.
    pub fn classify(&self, v: f64) -> Verdict {
        if v > self.upper {
            Verdict::Overconfident
        } else if v < self.lower {
            Verdict::Underconfident
        } else {
            Verdict::Consistent
        }
    }
}

/// The two-sided (1 − α) interval of an average of `count` chi-square variables whose
/// degrees of freedom add up to `total_dof`: `[χ²⁻¹(α/2, D)/count, χ²⁻¹(1 − α/2, D)/count]`.
pub fn chi2_average_interval(alpha: f64, total_dof: f64, count: f64) -> Interval {
    Interval {
        lower: chi2_inv(alpha / 2.0, total_dof) / count,
        upper: chi2_inv(1.0 - alpha / 2.0, total_dof) / count,
    }
}

/// The two-sided (1 − α) interval of `sum / count`, where `sum` has mean `mean` and
/// variance `var`, approximated by the scaled chi-square `g·χ²(h)` with the same two
/// moments: `g = var / (2 mean)`, `h = 2 mean² / var`. Returns the interval and `h`.
pub fn scaled_chi2_interval(alpha: f64, mean: f64, var: f64, count: f64) -> (Interval, f64) {
    let g = var / (2.0 * mean);
    let h = 2.0 * mean * mean / var;
    let iv = Interval {
        lower: g * chi2_inv(alpha / 2.0, h) / count,
        upper: g * chi2_inv(1.0 - alpha / 2.0, h) / count,
    };
    (iv, h)
}

/// What the variance of a time-averaged statistic's sum (over all runs and steps) rests on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SumVariance {
    /// Known under consistency: `2 D` for independent chi-square terms (NIS), or the
    /// filter's own prediction of the correlated NEES terms.
    Predicted(f64),
    /// Measured as `N s²` from the spread `s²` of the `runs` per-run sums, for a filter that
    /// supplies no model of its errors' correlation.
    RunSpread {
        /// The estimated variance of the sum over all runs.
        var: f64,
        /// The runs it was measured on (≥ 2).
        runs: usize,
    },
    /// Measured from a single run (a recording) by batch means ([`batch_spread`]): the sum
    /// over steps cut into `batches` blocks of consecutive steps, long enough that their sums
    /// are nearly independent, and the spread of those block sums.
    BatchSpread {
        /// The estimated variance of the sum over all runs and steps.
        var: f64,
        /// The blocks it was measured on (≥ [`MIN_BATCHES`]).
        batches: usize,
    },
    /// None of these (no prediction, fewer than two runs, and too few steps for batches).
    Unavailable,
}

/// The fewest blocks batch means uses: with 8, the t quantile has 7 degrees of freedom
/// (2.36 at 95%, against 1.96 for a known variance).
pub const MIN_BATCHES: usize = 8;
/// The most blocks batch means uses.
const MAX_BATCHES: usize = 32;
/// The fewest steps in a block.
pub const MIN_BATCH_STEPS: usize = 5;

/// The variance of `Σ series` estimated by batch means, and the number of blocks it rests
/// on; `None` below [`MIN_BATCHES`] blocks of [`MIN_BATCH_STEPS`] steps.
///
/// A time series of one run (a NEES per step, say) is correlated over time, so the spread
/// of its values says nothing about the spread of its sum. Cut into `B` blocks of `L`
/// consecutive steps, the block sums are nearly independent once `L` is well beyond the
/// integrated correlation time `τ = 1 + 2 Σ_l ρ_l`, and `Var(Σ) ≈ (T/L) s²` with `s²` their
/// sample variance (Law and Carson 1979). `τ` is estimated from the series with Sokal's
/// self-consistent window (the sum runs to the first lag `M ≥ 5 τ`); blocks are
/// `BLOCK_TAUS · τ` steps long, between 8 and 32 of them. Blocks only a few `τ` long still
/// share correlation across their edges and shrink the spread by about `τ/L`; it is divided
/// by `1 − τ/L` (at least 0.25) to make up for that (without it the false-alarm rate at
/// α = 5% was 9% on recordings 26 correlation times long, 14% on 10; with it, 6%). The steps that do not fill a block
/// are the first ones (a filter's start): they join the sum, not the spread.
pub fn batch_spread(series: &[f64]) -> Option<(f64, usize)> {
    let t = series.len();
    if t < MIN_BATCHES * MIN_BATCH_STEPS {
        return None;
    }
    let tau = correlation_time(series);
    let fit = (t as f64 / (BLOCK_TAUS * tau)).floor() as usize;
    // τ ≥ 1, so the blocks are never shorter than BLOCK_TAUS ≥ MIN_BATCH_STEPS steps.
    let batches = fit.clamp(MIN_BATCHES, MAX_BATCHES);
    let len = t / batches;
    let sums: Vec<f64> = series[t - batches * len..]
        .chunks(len)
        .map(|c| c.iter().sum())
        .collect();
    let b = batches as f64;
    let mean = sums.iter().sum::<f64>() / b;
    let s2 = sums.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / (b - 1.0);
    let short = (1.0 - tau / len as f64).max(0.25);
    Some((t as f64 / len as f64 * s2 / short, batches))
}

/// Block length in integrated correlation times.
const BLOCK_TAUS: f64 = 5.0;

/// The integrated correlation time `τ = 1 + 2 Σ_{l=1}^{M} ρ_l` of `series`, with Sokal's
/// window: the smallest `M ≥ 5 τ(M)` (at most a quarter of the series); at least 1.
fn correlation_time(series: &[f64]) -> f64 {
    let t = series.len();
    let mean = series.iter().sum::<f64>() / t as f64;
    let dev: Vec<f64> = series.iter().map(|v| v - mean).collect();
    let c0: f64 = dev.iter().map(|d| d * d).sum();
    if c0 <= 0.0 {
        return 1.0;
    }
    let rho = |lag: usize| dev[lag..].iter().zip(&dev).map(|(a, b)| a * b).sum::<f64>() / c0;
    let mut tau = 1.0;
    for lag in 1..=t / 4 {
        tau += 2.0 * rho(lag);
        if lag as f64 >= 5.0 * tau {
            break;
        }
    }
    // A short series truncates the window before a slow correlation has died out; the
    // first-order autoregression through ρ₁ does not truncate, and is the larger then.
    let r1 = rho(1).clamp(0.0, 0.99);
    tau.max((1.0 + r1) / (1.0 - r1)).max(1.0)
}

/// The two-sided (1 − α) gate interval of a time average `sum / count` whose sum has mean
/// `dof` under consistency, and its effective degrees of freedom.
///
/// - [`SumVariance::Predicted`]: the scaled chi-square with that variance (never below the
///   independent-terms value `2 D`), see [`scaled_chi2_interval`].
/// - [`SumVariance::RunSpread`]: the t interval `(D ± t_{1−α/2}(N−1) √var) / count` (the
///   per-run sums are independent, so their mean is t-distributed about its target whatever
///   the correlation inside a run), widened to contain the textbook interval: conservative.
/// - [`SumVariance::BatchSpread`]: the same t interval on the blocks' `B − 1` degrees of
///   freedom.
/// - [`SumVariance::Unavailable`]: NaN bounds and 0 degrees of freedom (no test).
pub fn gate_interval(alpha: f64, dof: f64, count: f64, var: SumVariance) -> (Interval, f64) {
    let floor = 2.0 * dof;
    match var {
        SumVariance::Predicted(v) => scaled_chi2_interval(alpha, dof, v.max(floor), count),
        SumVariance::RunSpread { var, runs: samples }
        | SumVariance::BatchSpread {
            var,
            batches: samples,
        } => {
            let naive = chi2_average_interval(alpha, dof, count);
            let t = StudentsT::new(0.0, 1.0, samples.saturating_sub(1).max(1) as f64)
                .map(|d| d.inverse_cdf(1.0 - alpha / 2.0))
                .unwrap_or(f64::INFINITY);
            let half = t * var.max(0.0).sqrt();
            // A time average of squared normalized errors is never negative: a lower end
            // below zero (a spread so wide the t interval reaches past it) is zero.
            let iv = Interval {
                lower: ((dof - half) / count).max(0.0).min(naive.lower),
                upper: ((dof + half) / count).max(naive.upper),
            };
            (iv, 2.0 * dof * dof / var.max(floor))
        }
        SumVariance::Unavailable => (
            Interval {
                lower: f64::NAN,
                upper: f64::NAN,
            },
            0.0,
        ),
    }
}

/// Whether a two-sided chi-square test on `dof` degrees of freedom at level α can tell a
/// covariance that is off by a factor of two from a correct one: both `χ²⁻¹(1 − α/2)/dof`
/// below 2 and `χ²⁻¹(α/2)/dof` above 1/2. At α = 0.05 this needs 23 degrees of freedom; a
/// single run of a scalar measurement has one.
pub fn has_power(alpha: f64, dof: f64) -> bool {
    dof > 0.0
        && chi2_inv(1.0 - alpha / 2.0, dof) / dof < 2.0
        && chi2_inv(alpha / 2.0, dof) / dof > 0.5
}

/// The two-sided standard-normal quantile `z_{1−α/2}`.
pub fn normal_two_sided_quantile(alpha: f64) -> f64 {
    Normal::standard().inverse_cdf(1.0 - alpha / 2.0)
}

/// The outcome of a consistency test.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Inside the acceptance interval.
    Consistent,
    /// Errors larger than the filter believes (statistic above `r2`): its P or S is too
    /// small.
    Overconfident,
    /// Errors smaller than the filter believes (statistic below `r1`): its P or S is too
    /// large.
    Underconfident,
    /// Some statistics above their interval, some below.
    Mixed,
    /// The innovations are correlated in time (an optimal filter's are white): the model
    /// misses dynamics, or its gain does not fit the noise.
    NotWhite,
    /// The errors (or innovations) do not average zero: a bias the filter does not model
    /// (a sensor offset or an unmodelled constant input).
    Biased,
    /// Passed, but with too few degrees of freedom for the test to mean anything.
    Inconclusive,
    /// The filter broke down in some runs (a covariance stopped being positive definite,
    /// or its error left its covariance by more than 1e154 standard deviations).
    Diverged,
    /// A covariance the filter inverts (P⁻, S or P) is too ill-conditioned for its NEES or
    /// NIS to mean anything (see `crate::filter::conditioning`): a noise parameter is far
    /// off the scale the measurements pin down. Fails the gate like a divergence.
    IllConditioned,
    /// The truth state overflowed or outgrew double precision: the truth model is unstable
    /// over this horizon, so nothing about the filter was tested. A problem to fix, not a
    /// verdict on the filter (the command line exits 2).
    TruthOverflow,
}

impl Verdict {
    /// Whether this verdict lets a CI gate pass.
    pub fn passes(self) -> bool {
        self == Verdict::Consistent
    }

    /// Short human wording.
    pub fn describe(self) -> &'static str {
        match self {
            Verdict::Consistent => "consistent",
            Verdict::Overconfident => "overconfident (errors larger than the filter believes)",
            Verdict::Underconfident => "underconfident (errors smaller than the filter believes)",
            Verdict::Mixed => "inconsistent (some statistics too high, some too low)",
            Verdict::NotWhite => "inconsistent (innovations correlated in time)",
            Verdict::Biased => "errors not zero-mean: a bias the filter does not model",
            Verdict::Inconclusive => "inconclusive (too little data for the test to have power)",
            Verdict::Diverged => {
                "diverged (the filter broke down in some runs: its covariance stopped being positive definite, or its error left it)"
            }
            Verdict::IllConditioned => {
                "ill-conditioned (a covariance the filter inverts lost its digits to rounding, so its NEES/NIS would be noise: a noise parameter is far off scale)"
            }
            Verdict::TruthOverflow => {
                "truth overflow (the truth state outgrows double precision over this horizon: the truth model is unstable; shorten the runs or fix the model; the filter was not tested)"
            }
        }
    }

    /// One-word label.
    pub fn label(self) -> &'static str {
        match self {
            Verdict::Consistent => "consistent",
            Verdict::Overconfident => "overconfident",
            Verdict::Underconfident => "underconfident",
            Verdict::Mixed => "mixed",
            Verdict::NotWhite => "not white",
            Verdict::Biased => "biased",
            Verdict::Inconclusive => "inconclusive",
            Verdict::Diverged => "diverged",
            Verdict::IllConditioned => "ill-conditioned",
            Verdict::TruthOverflow => "truth overflow",
        }
    }
}

/// Which tests the consistency gate applies.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum GateMode {
    /// Everything the summary shows: the time-averaged ANEES and ANIS, every state and
    /// measurement component's mean normalized squared error, and every measurement
    /// component's innovation whiteness.
    #[default]
    Full,
    /// The textbook gate: the time-averaged ANEES and ANIS only.
    Mean,
}

/// The level of each of `k` gate statistics so that a consistent filter fails the gate with
/// probability at most α (Šidák): `1 − (1 − α)^{1/k}`. Exactly α when the statistics are
/// independent, less when they are positively dependent (NEES and NIS are).
pub fn gate_alpha(alpha: f64, k: usize) -> f64 {
    1.0 - (1.0 - alpha).powf(1.0 / k.max(1) as f64)
}

/// Combine the verdicts of several statistics into one.
pub fn combine(verdicts: &[Verdict]) -> Verdict {
    for stop in [
        Verdict::TruthOverflow,
        Verdict::IllConditioned,
        Verdict::Diverged,
    ] {
        if verdicts.contains(&stop) {
            return stop;
        }
    }
    let over = verdicts.contains(&Verdict::Overconfident);
    let under = verdicts.contains(&Verdict::Underconfident);
    match (over, under) {
        (true, true) => Verdict::Mixed,
        (true, false) => Verdict::Overconfident,
        (false, true) => Verdict::Underconfident,
        _ if verdicts.contains(&Verdict::Mixed) => Verdict::Mixed,
        // A covariance that is off can bias a nonlinear filter's errors as a symptom (a
        // lag), so a second-moment failure outranks a failed mean here; the gate itself
        // reports a bias first when the bias explains every other failure
        // ([`super::ConsistencyReport::from_accumulator`]).
        _ if verdicts.contains(&Verdict::Biased) => Verdict::Biased,
        _ if verdicts.contains(&Verdict::NotWhite) => Verdict::NotWhite,
        _ if verdicts.contains(&Verdict::Inconclusive) => Verdict::Inconclusive,
        _ => Verdict::Consistent,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn average_interval_scales_by_count() {
        // N = 50 runs of a 2-D statistic: 100 degrees of freedom, divided by 50.
        let iv = chi2_average_interval(0.05, 100.0, 50.0);
        assert_relative_eq!(
            iv.lower,
            chi2_inv(0.025, 100.0) / 50.0,
            max_relative = 1e-15
        );
        assert_relative_eq!(
            iv.upper,
            chi2_inv(0.975, 100.0) / 50.0,
            max_relative = 1e-15
        );
        assert!(iv.lower < 2.0 && iv.upper > 2.0);
    }

    #[test]
    fn scaled_interval_reduces_to_chi2_without_correlation() {
        let (iv, h) = scaled_chi2_interval(0.05, 400.0, 800.0, 100.0);
        let naive = chi2_average_interval(0.05, 400.0, 100.0);
        assert_relative_eq!(h, 400.0, max_relative = 1e-14);
        assert_relative_eq!(iv.lower, naive.lower, max_relative = 1e-12);
        assert_relative_eq!(iv.upper, naive.upper, max_relative = 1e-12);
    }

    #[test]
    fn scaled_interval_widens_with_variance() {
        let (iv, h) = scaled_chi2_interval(0.05, 400.0, 8000.0, 100.0);
        let naive = chi2_average_interval(0.05, 400.0, 100.0);
        assert_relative_eq!(h, 40.0, max_relative = 1e-14);
        assert!(iv.lower < naive.lower && iv.upper > naive.upper);
    }

    #[test]
    fn gate_alpha_splits_the_level() {
        assert_relative_eq!(gate_alpha(0.05, 1), 0.05, max_relative = 1e-15);
        let a = gate_alpha(0.05, 2);
        assert_relative_eq!(1.0 - (1.0 - a) * (1.0 - a), 0.05, max_relative = 1e-12);
    }

    #[test]
    fn power_threshold() {
        // One run of a scalar measurement cannot see a factor-2 error; 50 degrees of freedom can.
        assert!(!has_power(0.05, 1.0));
        assert!(!has_power(0.05, 4.0));
        assert!(has_power(0.05, 50.0));
    }

    #[test]
    fn classify_and_combine() {
        let iv = Interval {
            lower: 0.5,
            upper: 1.5,
        };
        assert_eq!(iv.classify(2.0), Verdict::Overconfident);
        assert_eq!(iv.classify(0.1), Verdict::Underconfident);
        assert_eq!(iv.classify(1.0), Verdict::Consistent);
        assert_eq!(
            combine(&[Verdict::Consistent, Verdict::Overconfident]),
            Verdict::Overconfident
        );
        assert_eq!(
            combine(&[Verdict::Underconfident, Verdict::Overconfident]),
            Verdict::Mixed
        );
        assert_eq!(
            combine(&[Verdict::Consistent, Verdict::Inconclusive]),
            Verdict::Inconclusive
        );
        assert_eq!(
            combine(&[Verdict::Consistent, Verdict::Consistent]),
            Verdict::Consistent
        );
        assert_eq!(
            combine(&[Verdict::NotWhite, Verdict::Biased, Verdict::Consistent]),
            Verdict::Biased
        );
        assert_eq!(
            combine(&[Verdict::Overconfident, Verdict::Biased]),
            Verdict::Overconfident
        );
        assert_eq!(
            combine(&[Verdict::Diverged, Verdict::Biased]),
            Verdict::Diverged
        );
        assert!(!Verdict::Biased.passes());
    }

    /// `count` NEES series of `t` steps of a filter whose 5-state error is a stationary
    /// AR(1) vector (`e_k = ρ e_{k−1} + √(1 − ρ²) w_k`, unit variance) and whose P is
    /// `1/scale` (so its NEES is `scale · χ²(5)`, successive ones correlated by ρ²): how many
    /// time averages fall outside the batch-means gate interval at α = 0.05, and the block
    /// counts batch means chose.
    fn batch_outside(rho: f64, scale: f64, count: usize, seed: u64) -> (usize, Vec<usize>) {
        use rand::{RngExt, SeedableRng};
        let t = 500;
        let mut rng = crate::rng::SimRng::seed_from_u64(seed);
        let mut normal = || rng.sample::<f64, _>(rand_distr::StandardNormal);
        let (mut outside, mut blocks) = (0, Vec::new());
        for _ in 0..count {
            let mut e: Vec<f64> = (0..5).map(|_| normal()).collect();
            let series: Vec<f64> = (0..t)
                .map(|_| {
                    for x in e.iter_mut() {
                        *x = rho * *x + (1.0 - rho * rho).sqrt() * normal();
                    }
                    scale * e.iter().map(|x| x * x).sum::<f64>()
                })
                .collect();
            let (var, b) = batch_spread(&series).expect("500 steps are enough");
            blocks.push(b);
            let var = SumVariance::BatchSpread { var, batches: b };
            let (iv, _) = gate_interval(0.05, 5.0 * t as f64, t as f64, var);
            if !iv.contains(series.iter().sum::<f64>() / t as f64) {
                outside += 1;
            }
        }
        (outside, blocks)
    }

    /// A spread so wide that the t interval reaches below zero (a badly wrong filter's
    /// drifting NEES over one recording) is cut at zero, and still contains the textbook
    /// interval: a time average of squares is never negative.
    #[test]
    fn a_batch_means_interval_never_reaches_below_zero() {
        let (iv, _) = gate_interval(
            0.05,
            5.0,
            1.0,
            SumVariance::BatchSpread {
                var: 400.0,
                batches: 8,
            },
        );
        let naive = chi2_average_interval(0.05, 5.0, 1.0);
        assert_eq!(iv.lower, 0.0);
        assert!(iv.upper > naive.upper && iv.lower <= naive.lower);
    }

    #[test]
    fn batch_means_hold_the_false_alarm_rate_of_one_correlated_recording() {
        // 400 single recordings of 500 steps each, at error correlations ρ whose NEES
        // correlation times τ = (1 + ρ²)/(1 − ρ²) are 1, 4.6, 19.5 and 49 steps (500 steps
        // down to 10 correlation times). A consistent filter's time average must leave the
        // α = 0.05 interval at most as often as the binomial 99% band of 400 draws allows
        // (≤ 31 of 400), and not far less where the series is correlated (≥ 9): a
        // variance estimate that ignored the correlation would leave it on most draws at
        // ρ = 0.95, one that doubled it on almost none. Measured: 7, 14, 25, 24. White
        // series sit below the band: the interval is widened to contain the textbook one,
        // which is exact for them.
        for (rho, low) in [(0.0, 0), (0.8, 9), (0.95, 9), (0.98, 9)] {
            let (outside, blocks) = batch_outside(rho, 1.0, 400, 39);
            assert!(
                (low..=31).contains(&outside),
                "ρ = {rho}: {outside} of 400 outside the interval"
            );
            assert!(
                blocks
                    .iter()
                    .all(|b| (MIN_BATCHES..=MAX_BATCHES).contains(b))
            );
            if rho == 0.0 {
                // White steps: the blocks are as short as allowed (32 of them).
                assert!(blocks.iter().all(|&b| b == MAX_BATCHES), "{blocks:?}");
            }
            if rho == 0.98 {
                // 49 steps of correlation: 8 blocks, the fewest.
                assert!(blocks.iter().all(|&b| b == MIN_BATCHES), "{blocks:?}");
            }
        }
    }

    #[test]
    fn batch_means_catch_a_covariance_off_by_two_in_one_recording() {
        // The same recordings at ρ = 0.8 with P half and twice the truth (NEES ×2, ×0.5):
        // the interval is ±15% or so around 5 there, so both are caught on every draw
        // (measured 100 of 100 each).
        for scale in [2.0, 0.5] {
            let (outside, _) = batch_outside(0.8, scale, 100, 7);
            assert_eq!(outside, 100, "NEES × {scale}");
        }
    }

    #[test]
    fn batch_means_by_hand_on_a_series_without_correlation() {
        // 40 steps alternating ±1 (negative lag-1 correlation: τ taken as 1), offset by 0.4
        // in blocks 2, 3, 6 and 7 of 5 steps: 8 blocks of 5, block sums 1, −1, 3, 1, 1, −1,
        // 3, 1 (a block that starts at an even step sums +1 of the alternation, an odd one
        // −1). Their sample variance is 16/7; the sum's variance (40/5) · (16/7) over the
        // short-block factor 1 − τ/5 = 0.8, that is 160/7.
        let series: Vec<f64> = (0..40)
            .map(|i: usize| {
                let offset = if matches!(i / 5, 2 | 3 | 6 | 7) {
                    0.4
                } else {
                    0.0
                };
                if i.is_multiple_of(2) {
                    1.0 + offset
                } else {
                    -1.0 + offset
                }
            })
            .collect();
        let (var, blocks) = batch_spread(&series).unwrap();
        assert_eq!(blocks, MIN_BATCHES);
        assert!((var - 160.0 / 7.0).abs() < 1e-12, "{var}");
    }

    #[test]
    fn the_correlation_time_sums_the_autocorrelations_past_the_first() {
        // White noise plus an AR(1) part of equal variance with φ = 0.95: ρ_l = 0.5 · 0.95^l,
        // so τ = 1 + 2 · 0.5 · 0.95 / 0.05 = 20, though ρ₁ alone (0.475) would give the
        // autoregression's (1 + ρ₁)/(1 − ρ₁) = 2.8. On 20 000 steps Sokal's window gives 20
        // within a few steps (its standard error is about τ √(2 · 5τ / T) ≈ 2).
        use rand::{RngExt, SeedableRng};
        let mut rng = crate::rng::SimRng::seed_from_u64(5);
        let mut normal = || rng.sample::<f64, _>(rand_distr::StandardNormal);
        let mut y = normal();
        let series: Vec<f64> = (0..20_000)
            .map(|_| {
                y = 0.95 * y + (1.0 - 0.95f64 * 0.95).sqrt() * normal();
                y + normal()
            })
            .collect();
        let tau = correlation_time(&series);
        assert!((15.0..25.0).contains(&tau), "τ = {tau}");
    }

    #[test]
    fn the_correlation_window_stops_at_a_quarter_of_the_series() {
        // 200 steps of white noise plus a square wave of period 200 (0.7 for 100 steps, then
        // −0.7): ρ₁ is about 0.33, but ρ_l stays near it out to lag 50, so the window never
        // closes (it would need M ≥ 5τ) and stops at lag 50, with τ = 23.8 on this seed.
        // Past lag 50 the wave's correlation turns negative: a window let run on shrinks τ
        // before it closes (19.6 on this seed).
        use rand::{RngExt, SeedableRng};
        let mut rng = crate::rng::SimRng::seed_from_u64(11);
        let series: Vec<f64> = (0..200)
            .map(|i| {
                let wave = if i < 100 { 0.7 } else { -0.7 };
                wave + rng.sample::<f64, _>(rand_distr::StandardNormal)
            })
            .collect();
        let tau = correlation_time(&series);
        assert!(tau > 20.0, "τ = {tau}");
    }

    #[test]
    fn batch_means_need_eight_blocks_of_five_steps() {
        assert!(batch_spread(&[1.0; 39]).is_none());
        // A constant series has no spread; its correlation time is taken as one step.
        assert_eq!(batch_spread(&[1.0; 40]), Some((0.0, MIN_BATCHES)));
        assert_eq!(batch_spread(&[2.0; 400]), Some((0.0, MAX_BATCHES)));
        // A drift: its correlation window never closes, and stops at a quarter of the series;
        // the blocks are the fewest.
        let ramp: Vec<f64> = (0..100).map(f64::from).collect();
        assert_eq!(batch_spread(&ramp).map(|(_, b)| b), Some(MIN_BATCHES));
    }
}
