//! The centred whiteness of a log's innovations and the zero-mean test it widens: the
//! per-lag autocorrelations about the sample mean, with the variance inflation their
//! correlation implies.

use serde::Serialize;

use crate::fieldlog::analysis::SensorSums;
use crate::stats::{LaggedSums, Verdict, WhitenessStat, lagged_whiteness};

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
pub(super) fn centred_rho(s: &SensorSums, l: usize, j: usize) -> Option<(f64, f64)> {
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
pub(super) fn ar1_tail(l_max: usize, r_last: f64, rho1: f64, n: f64) -> f64 {
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
pub(super) fn mean_test(s: &SensorSums, j: usize, lags: usize, level: f64) -> Option<MeanTest> {
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
pub(super) fn centred_whiteness(
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

/// The factor by which strongly correlated innovations inflate the variance of the NIS
/// average: they carry fewer independent samples than updates, so the average's variance
/// grows by the components' mean factor (independent components add their sums'
/// variances).
pub(super) fn correlation_factor(s: &SensorSums, centred: &[CentredWhiteness]) -> f64 {
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

/// The lagged autocorrelations of each component, lag by lag, with their bands `z/√pairs`.
pub(super) fn whiteness_stats(s: &SensorSums, lags: usize, z: f64) -> Vec<WhitenessStat> {
    let sums = LaggedSums {
        pairs: &s.white_pairs,
        ab: &s.white_ab,
        a2: &s.white_a2,
        b2: &s.white_b2,
    };
    lagged_whiteness(&s.info.components, lags, &sums, z)
}
