//! The tuning objective: a dimensionless score of how far a filter's consistency statistics
//! are from their targets.
//!
//! For each gate statistic s (ANEES and ANIS; ANIS alone in NIS-only mode), with time
//! average `Ā_s`, degrees-of-freedom target `d_s`, gate interval `[a_s, b_s]`, and per-step
//! averages `A_sk` with intervals `[r1_sk, r2_sk]`, let `h(x; a, b)` be the log-distance
//! outside an interval (`ln(x/b)` above it, `ln(a/x)` below it, 0 inside). Then
//!
//! ```text
//! J = w_mean     Σ_s [ln(Ā_s / d_s)]²                      at the DOF target
//!   + w_interval Σ_s h(Ā_s; a_s, b_s)²                     outside the time-averaged interval
//!   + w_step     Σ_s (1/T_s) Σ_k h(A_sk; r1_sk, r2_sk)²    outside the per-step intervals
//!   + w_comp     [(1/n_x) Σ_j (ln c_j)² + (1/n_z) Σ_j (ln d_j)²]   per component
//!   + w_white    (1/(L n_z)) Σ_{l,j} ρ_lj²                  innovation whiteness
//!   + w_shape    (1/T) Σ_k [ln(Var_k(NEES) / 2n_x)]²         distribution shape (optional)
//!   + w_bias     [(1/n_x) Σ_j m_j² + (1/n_z) Σ_j μ_j²]        first moments (optional)
//! ```
//!
//! where `c_j` is the average of `e_j²/P_jj`, `d_j` of `ν_j²/S_jj`, and `ρ_lj` the lag-l
//! autocorrelation of `ν_j/√S_jj`; `m_j` and `μ_j` are the averages of `e_j/√P_jj` and
//! `ν_j/√S_jj`, 0 for a consistent filter. The second moments see a bias only through its
//! square, which a larger Q or R can make up for; the first-moment term is what pins a
//! structural change (a sensor offset, a step) where the gate's zero-mean tests judge it,
//! and is off by default (the noise parameters barely move a mean). J is zero exactly when every statistic sits at its target
//! and grows with the distance. Mean-only objectives (Chen et al. 2018) have whole curves of
//! zeros; the per-component and whiteness terms are what pin down per-axis parameters. A
//! filter that diverges scores +∞.
//!
//! **Restricted to a block** ([`Objective::restricted`], for the separable search over an
//! experiment's decoupled blocks): only the block's state and measurement components count,
//! in the components and whiteness terms as above. The pooled terms have no per-block sums,
//! so they get stand-ins:
//! - `mean`: the block's pooled component ratio at 1, `[ln(Σ_j∈B total_j / Σ_j∈B n_j)]²`,
//!   once for its states and once for its measurements: the block's own ANEES/ANIS per
//!   degree of freedom, up to the cross terms of P⁻¹ and S⁻¹ that a decoupled block has
//!   none of between blocks (and that only within a block the diagonal ratios ignore);
//! - `interval`, `per_step` and `shape`: none. Their intervals rest on the variance of a
//!   pooled NEES/NIS sum, and the sums carry neither per-component per-step averages nor
//!   per-component NEES variances. Nothing is lost for the answer: the search only has to
//!   find the block's best point, and the full gate (every term, pooled) still judges the
//!   assembled filter in the refinement and the confirmation.

pub use super::terms::{PerTerm, Terms, Weights};
use crate::stats::Accumulator;
use crate::stats::{
    Interval, SumVariance, chi2_average_interval, gate_alpha, gate_interval, scaled_chi2_interval,
};

/// Log-distance of `x` outside `iv` (0 inside).
fn outside(x: f64, iv: &Interval) -> f64 {
    if x > iv.upper {
        (x / iv.upper).ln()
    } else if x < iv.lower {
        (iv.lower / x).ln()
    } else {
        0.0
    }
}

/// Evaluates J on accumulated sums. Per-step intervals depend only on the degrees of
/// freedom and run counts, which do not change between candidates, so they are cached.
#[derive(Debug, Clone)]
pub struct Objective {
    /// Term weights.
    pub weights: Weights,
    /// Judge by NIS (and measurement components) alone.
    pub nis_only: bool,
    alpha: f64,
    cache: Vec<((u64, u64), Interval)>,
    nis_gate: Option<((u64, u64, u64), Interval)>,
    /// The block's state and measurement components, when restricted to one.
    block: Option<(Vec<usize>, Vec<usize>)>,
}

impl Objective {
    /// An objective at significance `alpha`.
    pub fn new(weights: Weights, nis_only: bool, alpha: f64) -> Self {
        Objective {
            weights,
            nis_only,
            alpha,
            cache: Vec::new(),
            nis_gate: None,
            block: None,
        }
    }

    /// This objective restricted to one decoupled block: its state components `states`
    /// and measurement components `measurements` (indices into the sums' component
    /// vectors), with the stand-ins for the pooled terms described in the module doc.
    pub fn restricted(mut self, states: &[usize], measurements: &[usize]) -> Self {
        self.block = Some((states.to_vec(), measurements.to_vec()));
        self
    }

    /// The time-averaged gate interval; the NIS one (variance 2·dof) is the same for every
    /// candidate and is served from the cache filled by [`Objective::prepare`].
    fn gate_interval(&self, dof: f64, var: SumVariance, count: f64) -> Interval {
        if let (Some((key, iv)), SumVariance::Predicted(v)) = (&self.nis_gate, var)
            && *key == (dof.to_bits(), v.to_bits(), count.to_bits())
        {
            return *iv;
        }
        let k = if self.nis_only { 1 } else { 2 };
        gate_interval(gate_alpha(self.alpha, k), dof, count, var).0
    }

    fn step_interval(&self, dof: f64, count: f64) -> Interval {
        let key = (dof.to_bits(), count.to_bits());
        match self.cache.iter().find(|(k, _)| *k == key) {
            Some((_, iv)) => *iv,
            None => chi2_average_interval(self.alpha, dof, count),
        }
    }

    /// Cache the per-step intervals `acc` needs, so later evaluations of candidates with the
    /// same measurement schedule compute no chi-square quantiles per step.
    pub fn prepare(&mut self, acc: &Accumulator) {
        let d: f64 = acc.nis_dof.iter().sum();
        let c: f64 = acc.nis_count.iter().sum();
        if d > 0.0 && c > 0.0 {
            let k = if self.nis_only { 1 } else { 2 };
            let iv = scaled_chi2_interval(gate_alpha(self.alpha, k), d, 2.0 * d, c).0;
            self.nis_gate = Some(((d.to_bits(), (2.0 * d).to_bits(), c.to_bits()), iv));
        }
        for (dof, count) in acc
            .nees_dof
            .iter()
            .zip(&acc.nees_count)
            .chain(acc.nis_dof.iter().zip(&acc.nis_count))
        {
            let key = (dof.to_bits(), count.to_bits());
            if *dof > 0.0 && *count > 0.0 && !self.cache.iter().any(|(k, _)| *k == key) {
                let iv = chi2_average_interval(self.alpha, *dof, *count);
                self.cache.push((key, iv));
            }
        }
    }

    /// Score `acc`. Diverged or non-finite statistics give `total = +∞`.
    pub fn evaluate(&self, acc: &Accumulator) -> Terms {
        self.score(acc, None)
    }

    /// J as a sum of squares: the residual vector r with `Σ r² = evaluate(acc).total`, one
    /// entry per time average, interval, step, component, lag and shape step (for a
    /// Gauss–Newton search); `None` when J is +∞.
    pub fn residuals(&self, acc: &Accumulator) -> Option<Vec<f64>> {
        let mut r = Vec::new();
        self.score(acc, Some(&mut r)).total.is_finite().then_some(r)
    }

    /// The terms of J; with `res`, each term's weighted square roots are pushed onto it.
    fn score(&self, acc: &Accumulator, res: Option<&mut Vec<f64>>) -> Terms {
        let inf = Terms {
            total: f64::INFINITY,
            ..Terms::default()
        };
        if acc.diverged_runs > 0 {
            return inf;
        }
        let w = self.weights;
        let mut s = Scored {
            t: Terms::default(),
            res,
        };
        if let Some((states, meas)) = &self.block {
            self.block_terms(acc, states, meas, &mut s);
            let t = &mut s.t;
            t.total = t.terms.mean + t.terms.components + t.terms.whiteness + t.terms.bias;
            return if t.total.is_finite() { s.t } else { inf };
        }
        if !self.average_terms(acc, &mut s) {
            return inf;
        }
        s.add(
            Term::Components,
            w.components,
            &log_ratios(&acc.meas_comp_total, &acc.meas_comp_samples),
        );
        if !self.nis_only {
            s.add(
                Term::Components,
                w.components,
                &log_ratios(&acc.state_comp_total, &acc.state_comp_samples),
            );
        }
        s.add(
            Term::Whiteness,
            w.whiteness,
            &lag_correlations(acc, |_| true),
        );
        if w.shape > 0.0 && !self.nis_only {
            s.add(Term::Shape, w.shape, &shape_deviations(acc));
        }
        // (`add` skips a term of weight 0, the bias's default.)
        s.add(
            Term::Bias,
            w.bias,
            &ratios(&acc.meas_mean_total, &acc.meas_comp_samples),
        );
        if !self.nis_only {
            s.add(
                Term::Bias,
                w.bias,
                &ratios(&acc.state_mean_total, &acc.state_mean_samples),
            );
        }
        let t = &mut s.t;
        t.total = t.terms.mean
            + t.terms.interval
            + t.terms.per_step
            + t.terms.components
            + t.terms.whiteness
            + t.terms.shape
            + t.terms.bias;
        if !t.total.is_finite() {
            return inf;
        }
        s.t
    }

    /// One decoupled block's terms: its pooled component ratios (the mean term), each of its
    /// components, and its measurements' lagged correlations.
    fn block_terms(&self, acc: &Accumulator, states: &[usize], meas: &[usize], s: &mut Scored<'_>) {
        let w = self.weights;
        let pooled = |total: &[f64], samples: &[f64], idx: &[usize]| -> Vec<f64> {
            let (a, b) = idx.iter().fold((0.0, 0.0), |(a, b), &j| {
                (
                    a + total.get(j).copied().unwrap_or(0.0),
                    b + samples.get(j).copied().unwrap_or(0.0),
                )
            });
            if b > 0.0 {
                vec![(a / b).ln()]
            } else {
                Vec::new()
            }
        };
        let pick = |total: &[f64], samples: &[f64], idx: &[usize]| -> Vec<f64> {
            idx.iter()
                .filter(|&&j| samples.get(j).is_some_and(|&n| n > 0.0))
                .map(|&j| (total[j] / samples[j]).ln())
                .collect()
        };
        let kinds = [
            (&acc.meas_comp_total, &acc.meas_comp_samples, meas, true),
            (
                &acc.state_comp_total,
                &acc.state_comp_samples,
                states,
                !self.nis_only,
            ),
        ];
        for (total, samples, idx, _) in kinds.into_iter().filter(|k| k.3) {
            s.add(Term::Mean, w.mean, &pooled(total, samples, idx));
            s.add(Term::Components, w.components, &pick(total, samples, idx));
        }
        let firsts = [
            (&acc.meas_mean_total, &acc.meas_comp_samples, meas, true),
            (
                &acc.state_mean_total,
                &acc.state_mean_samples,
                states,
                !self.nis_only,
            ),
        ];
        for (total, samples, idx, _) in firsts.into_iter().filter(|k| k.3) {
            let m: Vec<f64> = idx
                .iter()
                .filter(|&&j| samples.get(j).is_some_and(|&n| n > 0.0))
                .map(|&j| total[j] / samples[j])
                .collect();
            s.add(Term::Bias, w.bias, &m);
        }
        let n_z = acc.meas_comp_total.len().max(1);
        let rho = lag_correlations(acc, |o| meas.contains(&(o % n_z)));
        s.add(Term::Whiteness, w.whiteness, &rho);
    }

    /// The time averages' terms (ANIS, and ANEES unless NIS only): each average's log ratio
    /// to its target, its distance outside the gate interval, and the per-step distances.
    /// False when a variance is not finite (J is then +∞).
    fn average_terms(&self, acc: &Accumulator, s: &mut Scored<'_>) -> bool {
        let w = self.weights;
        let nis_var = SumVariance::Predicted(2.0 * acc.nis_dof.iter().sum::<f64>());
        let mut stats = vec![(&acc.nis_sum, &acc.nis_dof, &acc.nis_count, nis_var)];
        if !self.nis_only {
            stats.push((
                &acc.nees_sum,
                &acc.nees_dof,
                &acc.nees_count,
                acc.nees_sum_variance(),
            ));
        }
        for (sum, dof, count, var) in stats {
            let (total, d, c): (f64, f64, f64) =
                (sum.iter().sum(), dof.iter().sum(), count.iter().sum());
            if c <= 0.0 || d <= 0.0 {
                continue;
            }
            let avg = total / c;
            let var = match var {
                SumVariance::Predicted(v) => SumVariance::Predicted(v.max(2.0 * d)),
                other => other,
            };
            if matches!(var, SumVariance::Predicted(v) if !v.is_finite()) {
                return false;
            }
            let iv = self.gate_interval(d, var, c);
            s.add(Term::Mean, w.mean, &[(avg / (d / c)).ln()]);
            s.add(Term::Interval, w.interval, &[outside(avg, &iv)]);
            if w.per_step > 0.0 {
                let h: Vec<f64> = (0..sum.len())
                    .filter(|&k| count[k] > 0.0 && dof[k] > 0.0)
                    .map(|k| outside(sum[k] / count[k], &self.step_interval(dof[k], count[k])))
                    .collect();
                s.add(Term::PerStep, w.per_step, &h);
            }
        }
        true
    }
}

/// Which term of J a deviation adds to.
#[derive(Debug, Clone, Copy)]
enum Term {
    Mean,
    Interval,
    PerStep,
    Components,
    Whiteness,
    Shape,
    Bias,
}

/// J's terms as they accumulate, with the residuals behind them where asked for.
struct Scored<'r> {
    t: Terms,
    res: Option<&'r mut Vec<f64>>,
}

impl Scored<'_> {
    /// Adds `weight · mean(x²)` over `xs` to `term` and pushes `√(weight/len) · x`.
    fn add(&mut self, term: Term, weight: f64, xs: &[f64]) {
        if xs.is_empty() || weight == 0.0 {
            return;
        }
        let scale = weight / xs.len() as f64;
        let terms = &mut self.t.terms;
        let slot = match term {
            Term::Mean => &mut terms.mean,
            Term::Interval => &mut terms.interval,
            Term::PerStep => &mut terms.per_step,
            Term::Components => &mut terms.components,
            Term::Whiteness => &mut terms.whiteness,
            Term::Shape => &mut terms.shape,
            Term::Bias => &mut terms.bias,
        };
        *slot += scale * xs.iter().map(|x| x * x).sum::<f64>();
        if let Some(r) = self.res.as_deref_mut() {
            r.extend(xs.iter().map(|x| scale.sqrt() * x));
        }
    }
}

/// Each component's ratio of its total to its samples, over the components with samples.
fn ratios(total: &[f64], samples: &[f64]) -> Vec<f64> {
    total
        .iter()
        .zip(samples)
        .filter(|(_, b)| **b > 0.0)
        .map(|(a, b)| a / b)
        .collect()
}

/// Each component's log ratio of its total to its samples, over the components with
/// samples.
fn log_ratios(total: &[f64], samples: &[f64]) -> Vec<f64> {
    total
        .iter()
        .zip(samples)
        .filter(|(_, b)| **b > 0.0)
        .map(|(a, b)| (a / b).ln())
        .collect()
}

/// The normalized lagged correlations of the innovations (lag-major over the measurement
/// components), for the entries `keep` accepts that have pairs.
fn lag_correlations(acc: &Accumulator, keep: impl Fn(usize) -> bool) -> Vec<f64> {
    (0..acc.white_ab.len())
        .filter(|&o| keep(o))
        .filter_map(|o| {
            let den = (acc.white_a2[o] * acc.white_b2[o]).sqrt();
            (acc.white_pairs[o] > 0.0 && den > 0.0).then(|| acc.white_ab[o] / den)
        })
        .collect()
}

/// Per step with two or more runs, the log ratio of the NEES's spread over the runs to the
/// χ² spread a consistent filter's NEES has (2 · dof).
fn shape_deviations(acc: &Accumulator) -> Vec<f64> {
    (0..acc.nees_sum.len())
        .filter_map(|k| {
            let c = acc.nees_count[k];
            if c <= 1.0 {
                return None;
            }
            let mean = acc.nees_sum[k] / c;
            let var = acc.nees_sq[k] / c - mean * mean;
            let target = 2.0 * acc.nees_dof[k] / c;
            (var > 0.0).then(|| (var / target).ln())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sums of 2 states and 2 measurements in which component 0 of each is off (ratio 4)
    /// and component 1 at its target, with lag-1 whiteness off only on measurement 0.
    fn sums() -> Accumulator {
        let mut acc = Accumulator::new(3, 2, 2, 1);
        acc.state_comp_total = vec![40.0, 10.0];
        acc.state_comp_samples = vec![10.0, 10.0];
        acc.meas_comp_total = vec![40.0, 10.0];
        acc.meas_comp_samples = vec![10.0, 10.0];
        acc.white_ab = vec![5.0, 0.0];
        acc.white_a2 = vec![10.0, 10.0];
        acc.white_b2 = vec![10.0, 10.0];
        acc.white_pairs = vec![10.0, 10.0];
        acc
    }

    #[test]
    fn the_first_moment_term_scores_each_components_mean_and_only_when_weighted() {
        // Means: states 0.5 and 0 (samples 10), measurements −0.2 and 0.4 (samples 10).
        let mut acc = sums();
        acc.state_mean_total = vec![5.0, 0.0];
        acc.state_mean_samples = vec![10.0, 10.0];
        acc.meas_mean_total = vec![-2.0, 4.0];
        let off = Objective::new(Weights::default(), false, 0.05).evaluate(&acc);
        assert_eq!(off.terms.bias, 0.0, "off by default");
        let w = Weights {
            bias: 3.0,
            ..Weights::default()
        };
        let o = Objective::new(w, false, 0.05);
        let t = o.evaluate(&acc);
        // 3 · [(0.5² + 0)/2 + (0.04 + 0.16)/2] = 3 · 0.225.
        assert!((t.terms.bias - 0.675).abs() < 1e-12, "{t:?}");
        assert!((t.total - off.total - 0.675).abs() < 1e-12);
        let r = o.residuals(&acc).unwrap();
        assert!((r.iter().map(|x| x * x).sum::<f64>() - t.total).abs() < 1e-9);
        // NIS only: the measurements' means alone.
        let nis = Objective::new(w, true, 0.05).evaluate(&acc);
        assert!((nis.terms.bias - 0.3).abs() < 1e-12, "{nis:?}");
        // A block: its own components, state 0 and measurement 1: 3 · (0.25 + 0.16).
        let b = Objective::new(w, false, 0.05)
            .restricted(&[0], &[1])
            .evaluate(&acc);
        assert!((b.terms.bias - 1.23).abs() < 1e-12, "{b:?}");
        let parts = b.terms.mean + b.terms.components + b.terms.whiteness + b.terms.bias;
        assert!((b.total - parts).abs() < 1e-12, "{b:?}");
        // A component without samples has no mean: it is left out, not a 0/0.
        acc.state_mean_samples = vec![10.0, 0.0];
        acc.meas_comp_samples = vec![10.0, 0.0];
        for o in [
            Objective::new(w, false, 0.05),
            Objective::new(w, false, 0.05).restricted(&[0, 1], &[0, 1]),
        ] {
            let t = o.evaluate(&acc);
            assert!(t.terms.bias.is_finite() && t.total.is_finite(), "{t:?}");
        }
        let mut named = Weights::default();
        assert!(named.set("bias", 1.0).is_ok() && named.bias == 1.0);
    }

    #[test]
    fn a_restricted_objective_scores_only_its_blocks_components() {
        let o = Objective::new(Weights::default(), false, 0.05);
        let right = o.clone().restricted(&[1], &[1]).evaluate(&sums());
        assert_eq!(right.total, 0.0, "{right:?}");
        let wrong = o.restricted(&[0], &[0]).evaluate(&sums());
        // mean: (ln 4)² for the states and for the measurements; components the same;
        // whiteness: ρ = 0.5.
        let l = 4f64.ln().powi(2);
        assert!((wrong.terms.mean - 2.0 * l).abs() < 1e-12, "{wrong:?}");
        assert!(
            (wrong.terms.components - 2.0 * l).abs() < 1e-12,
            "{wrong:?}"
        );
        assert!((wrong.terms.whiteness - 0.25).abs() < 1e-12, "{wrong:?}");
        assert_eq!(wrong.terms.interval + wrong.terms.per_step, 0.0);
        // J is the sum of the block's terms.
        assert!((wrong.total - (4.0 * l + 0.25)).abs() < 1e-12, "{wrong:?}");
    }

    /// Two steps of two runs: NIS sums 6 and 10 on 4 degrees of freedom a step (ANIS = 4 per
    /// sample against a target of 2, ratio 2), NEES sums 12 and 12 on 8 (ANEES = 6 against 4,
    /// ratio 1.5); the NEES's spread over the runs 16 at step 1 and 8 at step 2 against the
    /// χ² spread 2 · 8 / 2 = 8 (ratios 2 and 1).
    fn averages() -> Accumulator {
        let mut acc = Accumulator::new(2, 2, 2, 1);
        acc.runs = 2;
        acc.nis_sum = vec![6.0, 10.0];
        acc.nis_dof = vec![4.0, 4.0];
        acc.nis_count = vec![2.0, 2.0];
        acc.nees_sum = vec![12.0, 12.0];
        acc.nees_dof = vec![8.0, 8.0];
        acc.nees_count = vec![2.0, 2.0];
        // Var = sq/c − mean²: 52 − 36 = 16 and 44 − 36 = 8.
        acc.nees_sq = vec![104.0, 88.0];
        acc
    }

    fn only(term: &str) -> Weights {
        let mut w = Weights::ZERO;
        w.set(term, 1.0).unwrap();
        w
    }

    #[test]
    fn the_mean_term_is_each_time_averages_squared_log_ratio_to_its_dof_target() {
        let acc = averages();
        let l2 = 2f64.ln().powi(2);
        let full = Objective::new(only("mean"), false, 0.05).evaluate(&acc);
        let want = l2 + 1.5f64.ln().powi(2);
        assert!((full.total - want).abs() < 1e-12, "{full:?}, want {want}");
        let nis = Objective::new(only("mean"), true, 0.05).evaluate(&acc);
        assert!(
            (nis.total - l2).abs() < 1e-12,
            "NIS only: {nis:?}, want {l2}"
        );
        // The residuals are J's square roots, term by term.
        let r = Objective::new(only("mean"), false, 0.05)
            .residuals(&acc)
            .unwrap();
        assert_eq!(r.len(), 2);
        assert!((r[0] - 2f64.ln()).abs() < 1e-12 && (r[1] - 1.5f64.ln()).abs() < 1e-12);
    }

    #[test]
    fn the_shape_term_is_the_mean_squared_log_ratio_of_the_nees_spread_to_chi2s() {
        let t = Objective::new(only("shape"), false, 0.05).evaluate(&averages());
        let want = 2f64.ln().powi(2) / 2.0;
        assert!((t.terms.shape - want).abs() < 1e-12, "{t:?}, want {want}");
        assert_eq!(t.total, t.terms.shape);
        // A step of one run has no spread, and NIS-only scoring has no NEES.
        let mut one = averages();
        one.nees_count = vec![2.0, 1.0];
        let t = Objective::new(only("shape"), false, 0.05).evaluate(&one);
        assert!((t.terms.shape - 2f64.ln().powi(2)).abs() < 1e-12, "{t:?}");
        let t = Objective::new(only("shape"), true, 0.05).evaluate(&averages());
        assert_eq!(t.total, 0.0);
    }

    #[test]
    fn a_nees_variance_that_is_not_finite_scores_infinity() {
        // The filters' own predicted variance of the NEES sum overflowed: no interval can be
        // drawn around ANEES, so no candidate with it can be ranked.
        let mut acc = averages();
        acc.null_var_runs = 2;
        acc.nees_null_var = f64::INFINITY;
        let o = Objective::new(Weights::default(), false, 0.05);
        assert_eq!(o.evaluate(&acc).total, f64::INFINITY);
        assert_eq!(o.residuals(&acc), None);
        // NIS-only scoring does not read the NEES.
        let t = Objective::new(Weights::default(), true, 0.05).evaluate(&acc);
        assert!(t.total.is_finite(), "{t:?}");
    }
}
