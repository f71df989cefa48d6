//! Consistency statistics: NEES, NIS, their Monte Carlo averages, chi-square acceptance
//! intervals, per-component and whiteness diagnostics, and the verdict.
//!
//! Notation (Bar-Shalom, Li, Kirubarajan 2001, §5.4): over N independent runs,
//! `ANEES_k = (1/N) Σ_i e_ik' P_ik⁻¹ e_ik`, and under a consistent filter
//! `N · ANEES_k ~ χ²(N n_x)`, so its two-sided (1 − α) acceptance interval is
//! `[χ²⁻¹(α/2, N n_x)/N, χ²⁻¹(1 − α/2, N n_x)/N]`. The same holds for ANIS with the
//! dimension of the measurement used at that step.
//!
//! The time-averaged statistics need care. Innovations of a consistent filter are white, so
//! the sum of NIS over all runs and steps is exactly χ² with `Σ N n_z,k` degrees of freedom.
//! Estimation errors are *not* white: `e_k = A_k e_{k−1} + noise` with
//! `A_k = (I − K_k H_k) F_k`, so the sum of NEES over time has the right mean but a larger
//! variance than the naive `χ²(N T n_x)` assumes, and a gate built on the naive interval
//! raises false alarms far more often than α. The engine therefore also accumulates the
//! variance of the per-run NEES sum that the filter itself predicts under consistency
//! (Isserlis' theorem: `Cov(ε_j, ε_k) = 2 tr(P_k⁻¹ Φ_kj P_j Φ_kj')`), and the gate uses a
//! moment-matched scaled chi-square `g·χ²(h)` (Satterthwaite 1946) with that mean and
//! variance. When the errors are uncorrelated this reduces to the naive interval exactly.

mod attribution;
mod diagnostics;
mod interval;
mod null_variance;
mod recorder;
mod report;
mod sums;

pub use attribution::{Diagnosis, Finding, Suspect, blame};
pub use diagnostics::{ComponentStat, WhitenessStat, WhitenessTest, whiteness_tests};
pub(crate) use diagnostics::{LaggedSums, lagged_whiteness};

pub use interval::{
    GateMode, Interval, MIN_BATCH_STEPS, MIN_BATCHES, SumVariance, Verdict, batch_spread,
    chi2_average_interval, chi2_inv, combine, gate_alpha, gate_interval, has_power,
    normal_two_sided_quantile, scaled_chi2_interval,
};
pub use null_variance::{ComponentNullVariance, NeesNullVariance};
pub use recorder::RunRecorder;
pub use report::{ConsistencyReport, GateSpec, StatisticSummary, diagnose, gate_deviates};
pub use sums::{Accumulator, Divergence, StopCause};
