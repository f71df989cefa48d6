//! How far one record pins each free parameter: the profile-likelihood interval around the
//! maximum-likelihood estimate, and the range along each parameter over which the record
//! still passes the consistency gate.
//!
//! The observed-information interval `θ̂ · exp(±1.96 se/θ̂)` assumes `−log L` is quadratic in
//! log θ. On a short record of a nonlinear filter it is not (on 500-step ctrv records the
//! yaw-acceleration interval covers the truth on 88 of 100), and at a bound it says
//! nothing. The profile interval does not assume the shape: it is every θ_i whose profile
//! `p(θ_i) = min over the other free parameters of −log L` lies within `c` nats of the
//! minimum, with `c = χ²₁(level)/2` (Wilks). For a parameter at its bound (0), the
//! likelihood-ratio statistic is ½χ²₀ + ½χ²₁ under the truth, so the one-sided level uses
//! `c = χ²₁(2·level − 1)/2` and the interval starts at 0.
//!
//! The profile is traced in φ = log θ_i from the estimate outwards on each side. The signed
//! root `√(2(p − p̂))` is close to linear in φ, so each step aims it at `√(2c)` along the
//! line through the estimate, inside a bracket once one is found; the other parameters are
//! re-fitted at each point by Newton steps in their logs, warm-started from the last point.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

mod gate;

pub use gate::{GateRanges, gate_ranges};

use super::ml::MlEstimate;
use crate::stats::chi2_inv;

/// Farthest the profile is traced from an estimate inside the bounds, in log θ: a factor
/// of 10⁴ either way.
const MAX_SPAN: f64 = 9.210_340_371_976_184;
/// Farthest it is traced up from an estimate at its bound (a factor of e⁶⁰: from wherever
/// the search left a parameter the data cannot tell from zero, to any value a noise can
/// take).
const MAX_SPAN_AT_BOUND: f64 = 60.0;
/// An end is found when the profile there is within this of `c` (nats): a hundredth of a
/// nat moves a 95% end by about half a percent of its standard error.
const END_TOL: f64 = 0.01;
/// The re-fit of the other parameters stops when its quadratic model predicts less than
/// this still to gain (nats).
const REFIT_TOL: f64 = 1e-4;
/// Step of the differenced gradient and curvature, in log θ.
const DIFF_STEP: f64 = 1e-3;

/// One end of a range: a value the trace reached, or the farthest it went without reaching
/// the end (the range extends at least that far).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RangeEnd {
    /// The value (the parameter's unit).
    pub value: f64,
    /// Whether the range ends here (false: the trace stopped at its limit, and the data
    /// allow values beyond it).
    pub reached: bool,
}

/// The values of one parameter a record supports.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Range {
    /// Lower end: 0, reached, for a parameter at its bound and for one whose profile stays
    /// within the level down to 10⁻⁴ of the estimate (the record cannot tell it from 0).
    pub lower: RangeEnd,
    /// Upper end.
    pub upper: RangeEnd,
}

impl Range {
    /// Whether `v` lies in the range (an end not reached is open).
    pub fn contains(&self, v: f64) -> bool {
        (v >= self.lower.value || !self.lower.reached)
            && (v <= self.upper.value || !self.upper.reached)
    }
}

/// The profile-likelihood intervals of an estimate's free parameters.
#[derive(Debug, Clone, Serialize)]
pub struct LikelihoodRanges {
    /// Confidence level (0.95: each interval covers the truth on 95% of records).
    pub level: f64,
    /// One per parameter: `None` for a fixed one, and for one whose profile could not be
    /// traced (the likelihood is higher away from the estimate: it was not the maximum).
    /// Where the filter fails before the level is reached, the end is put at the failure
    /// (the record excludes what the filter cannot run at).
    pub ranges: Vec<Option<Range>>,
    /// Likelihood evaluations the trace took.
    pub evaluations: usize,
}

/// The profile-likelihood interval at `level` (e.g. 0.95) of each free parameter of `est`,
/// the maximum of `−log L = nll(θ)` (`None` where the filter has no likelihood). Traced from
/// the estimate; `fixed[i]` marks the parameters held.
pub fn likelihood_ranges(
    nll: &dyn Fn(&[f64]) -> Option<f64>,
    est: &MlEstimate,
    fixed: &[bool],
    level: f64,
) -> LikelihoodRanges {
    let free: Vec<usize> = (0..fixed.len()).filter(|&i| !fixed[i]).collect();
    let mut tracer = Profile {
        nll,
        theta: est.theta.clone(),
        active: free
            .iter()
            .copied()
            .filter(|i| !est.at_bound.contains(i))
            .collect(),
        best: est.neg_log_likelihood,
        evaluations: 0,
    };
    let hess = tracer.curvature();
    let mut ranges = vec![None; fixed.len()];
    for &i in &free {
        let at_bound = est.at_bound.contains(&i);
        let c = if at_bound {
            0.5 * chi2_inv(2.0 * level - 1.0, 1.0)
        } else {
            0.5 * chi2_inv(level, 1.0)
        };
        ranges[i] = tracer.range(i, at_bound, c, hess.as_ref());
    }
    LikelihoodRanges {
        level,
        ranges,
        evaluations: tracer.evaluations,
    }
}

/// `−log L` and where the profile trace is.
struct Profile<'a> {
    nll: &'a dyn Fn(&[f64]) -> Option<f64>,
    /// The estimate.
    theta: Vec<f64>,
    /// Free parameters not at their bound (the ones re-fitted).
    active: Vec<usize>,
    /// `−log L` at the estimate.
    best: f64,
    evaluations: usize,
}

impl Profile<'_> {
    /// `−log L` at the estimate with the parameters `at` set to `exp(phi)`.
    fn value(&mut self, at: &[usize], phi: &[f64]) -> Option<f64> {
        let mut t = self.theta.clone();
        for (&i, &p) in at.iter().zip(phi) {
            t[i] = p.exp();
        }
        self.evaluations += 1;
        (self.nll)(&t).filter(|v| v.is_finite())
    }

    /// The curvature of `−log L` in log θ over the active parameters at the estimate
    /// (second differences), `None` where the filter fails next to it.
    fn curvature(&mut self) -> Option<DMatrix<f64>> {
        let at = self.active.clone();
        let phi0: Vec<f64> = at.iter().map(|&i| self.theta[i].ln()).collect();
        let h = DIFF_STEP;
        let k = at.len();
        let mut hess = DMatrix::zeros(k, k);
        let shifted = |s: &mut Self, moves: &[(usize, f64)]| {
            let mut p = phi0.clone();
            for &(j, d) in moves {
                p[j] += d;
            }
            s.value(&at, &p)
        };
        let f0 = self.best;
        for a in 0..k {
            let up = shifted(self, &[(a, h)])?;
            let down = shifted(self, &[(a, -h)])?;
            hess[(a, a)] = (up - 2.0 * f0 + down) / (h * h);
            for b in 0..a {
                let pp = shifted(self, &[(a, h), (b, h)])?;
                let pm = shifted(self, &[(a, h), (b, -h)])?;
                let mp = shifted(self, &[(a, -h), (b, h)])?;
                let mm = shifted(self, &[(a, -h), (b, -h)])?;
                let v = (pp - pm - mp + mm) / (4.0 * h * h);
                hess[(a, b)] = v;
                hess[(b, a)] = v;
            }
        }
        Some(hess)
    }

    /// The interval of parameter `i` (at its bound or not) at `c` nats.
    fn range(
        &mut self,
        i: usize,
        at_bound: bool,
        c: f64,
        hess: Option<&DMatrix<f64>>,
    ) -> Option<Range> {
        let others: Vec<usize> = self.active.iter().copied().filter(|&j| j != i).collect();
        // The quadratic model's end of the interval: the first step.
        let d0 = match (hess, self.active.iter().position(|&j| j == i)) {
            (Some(h), Some(pi)) => h
                .clone()
                .cholesky()
                .map(|ch| (2.0 * c * ch.inverse()[(pi, pi)]).sqrt())
                .filter(|d| d.is_finite() && *d > 1e-6)
                .unwrap_or(1.0),
            _ => 1.0,
        };
        let upper = self.end(i, &others, 1.0, d0, c, at_bound)?;
        let lower = if at_bound {
            RangeEnd {
                value: 0.0,
                reached: true,
            }
        } else {
            self.end(i, &others, -1.0, d0, c, false)?
        };
        Some(Range { lower, upper })
    }

    /// One end of the interval of parameter `i`: traced from the estimate along `side` (±1)
    /// with first step `d0`, until the profile is `c` nats above the estimate.
    fn end(
        &mut self,
        i: usize,
        others: &[usize],
        side: f64,
        d0: f64,
        c: f64,
        at_bound: bool,
    ) -> Option<RangeEnd> {
        let phi_hat = self.theta[i].ln();
        let span = if at_bound {
            MAX_SPAN_AT_BOUND
        } else {
            MAX_SPAN
        };
        let target = (2.0 * c).sqrt();
        let mut warm: Vec<f64> = others.iter().map(|&j| self.theta[j].ln()).collect();
        // Bracket in distance from the estimate: inside (root below target), outside.
        let (mut inside, mut outside): ((f64, f64), Option<(f64, f64)>) = ((0.0, 0.0), None);
        let mut d = d0.min(span);
        let at = |d: f64| (phi_hat + side * d).exp();
        for _ in 0..40 {
            let root = match self.refit(i, phi_hat + side * d, others, &mut warm) {
                Some(p) if p < self.best - END_TOL => return None,
                Some(p) => (2.0 * (p - self.best).max(0.0)).sqrt(),
                // The filter fails here: no likelihood, so the record excludes it.
                None => f64::INFINITY,
            };
            let gap = 0.5 * root * root - c;
            if gap.abs() <= END_TOL {
                return Some(RangeEnd {
                    value: at(d),
                    reached: true,
                });
            }
            if root < target {
                inside = (d, root);
                if d >= span {
                    // Traced down past 10⁻⁴ of the estimate (or e⁻⁶⁰ of a bound's):
                    // the record cannot tell the parameter from zero, its bound.
                    return Some(RangeEnd {
                        value: if side < 0.0 { 0.0 } else { at(span) },
                        reached: side < 0.0,
                    });
                }
            } else {
                outside = Some((d, root));
            }
            d = match outside {
                None => {
                    // Aim the signed root along the line through the estimate, at least
                    // half again as far and at most four times.
                    let aim = if root > 1e-3 {
                        d * target / root
                    } else {
                        4.0 * d
                    };
                    aim.clamp(1.5 * d, 4.0 * d).min(span)
                }
                Some((o, ro)) => {
                    let (n, rn) = inside;
                    if o - n < 1e-4 {
                        return Some(RangeEnd {
                            value: at(0.5 * (o + n)),
                            reached: true,
                        });
                    }
                    // Secant through the bracket's ends where the outer root is finite,
                    // kept off the ends; bisection otherwise.
                    let s = if ro.is_finite() {
                        n + (target - rn) * (o - n) / (ro - rn)
                    } else {
                        0.5 * (n + o)
                    };
                    s.clamp(n + 0.1 * (o - n), o - 0.1 * (o - n))
                }
            };
        }
        outside.map(|(o, _)| RangeEnd {
            value: at(o),
            reached: true,
        })
    }

    /// The profile at `log θ_i = phi_i`: `−log L` minimized over the `others` (their logs
    /// `warm`, updated to the minimum), from `warm` and, where it has walked more than half
    /// an e-fold away, from the estimate as well (in log θ a parameter near zero sits on a
    /// plateau whose gradient vanishes: a trace that stepped onto it where the others' best
    /// was zero would stay there when the best moves back up). `None` where the filter fails.
    fn refit(&mut self, i: usize, phi_i: f64, others: &[usize], warm: &mut [f64]) -> Option<f64> {
        let home: Vec<f64> = others.iter().map(|&j| self.theta[j].ln()).collect();
        let far = warm.iter().zip(&home).any(|(w, h)| (w - h).abs() > 0.5);
        let mut from_warm = warm.to_vec();
        let a = self.descend(i, phi_i, others, &mut from_warm);
        if !far {
            warm.copy_from_slice(&from_warm);
            return a;
        }
        let mut from_home = home;
        let b = self.descend(i, phi_i, others, &mut from_home);
        match (a, b) {
            (Some(va), Some(vb)) if vb < va => {
                warm.copy_from_slice(&from_home);
                Some(vb)
            }
            (None, Some(vb)) => {
                warm.copy_from_slice(&from_home);
                Some(vb)
            }
            (a, _) => {
                warm.copy_from_slice(&from_warm);
                a
            }
        }
    }

    /// Newton steps on differenced curvature over the `others` from `warm` (updated to
    /// where they stop), each at most one e-fold long, with θ_i at `exp(phi_i)`.
    fn descend(&mut self, i: usize, phi_i: f64, others: &[usize], warm: &mut [f64]) -> Option<f64> {
        let mut at = vec![i];
        at.extend_from_slice(others);
        let mut phi = vec![phi_i];
        phi.extend_from_slice(warm);
        let mut v = self.value(&at, &phi)?;
        if others.is_empty() {
            return Some(v);
        }
        for _ in 0..20 {
            // A neighbour without a likelihood (a failure boundary next to this point):
            // stop here, with the value this point has.
            let Some((g, h)) = self.local_model(&at, &phi, v) else {
                break;
            };
            let h = floored(&h);
            let Some(ch) = h.cholesky() else {
                break;
            };
            let mut step = -ch.solve(&g);
            if 0.5 * g.dot(&ch.solve(&g)) < REFIT_TOL {
                break;
            }
            let longest = step.amax();
            if longest > 1.0 {
                step /= longest;
            }
            let mut t = 1.0;
            let mut moved = false;
            for _ in 0..20 {
                let mut trial = phi.clone();
                for (k, s) in step.iter().enumerate() {
                    trial[k + 1] += t * s;
                }
                if let Some(tv) = self.value(&at, &trial)
                    && tv < v
                {
                    phi = trial;
                    v = tv;
                    moved = true;
                    break;
                }
                t *= 0.5;
            }
            if !moved {
                break;
            }
        }
        warm.copy_from_slice(&phi[1..]);
        Some(v)
    }

    /// Central-difference gradient and curvature over `phi[1..]` (the re-fitted
    /// parameters), `v` being the value at `phi`.
    fn local_model(
        &mut self,
        at: &[usize],
        phi: &[f64],
        v: f64,
    ) -> Option<(DVector<f64>, DMatrix<f64>)> {
        let k = phi.len() - 1;
        let h = DIFF_STEP;
        let mut g = DVector::zeros(k);
        let mut hess = DMatrix::zeros(k, k);
        let mut p = phi.to_vec();
        for a in 0..k {
            p[a + 1] = phi[a + 1] + h;
            let up = self.value(at, &p)?;
            p[a + 1] = phi[a + 1] - h;
            let down = self.value(at, &p)?;
            p[a + 1] = phi[a + 1];
            g[a] = (up - down) / (2.0 * h);
            hess[(a, a)] = (up - 2.0 * v + down) / (h * h);
            for b in 0..a {
                let mut corner = |da: f64, db: f64| {
                    let mut q = phi.to_vec();
                    q[a + 1] += da;
                    q[b + 1] += db;
                    self.value(at, &q)
                };
                let x = (corner(h, h)? - corner(h, -h)? - corner(-h, h)? + corner(-h, -h)?)
                    / (4.0 * h * h);
                hess[(a, b)] = x;
                hess[(b, a)] = x;
            }
        }
        Some((g, hess))
    }
}

/// `h` with its eigenvalues floored at a millionth of the largest (and at 1e-6 nats per
/// e-fold²), so Newton steps over a direction the estimate did not curve stay finite.
fn floored(h: &DMatrix<f64>) -> DMatrix<f64> {
    if h.nrows() == 0 {
        return h.clone();
    }
    let eig = h.clone().symmetric_eigen();
    let top = eig.eigenvalues.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
    let floor = (1e-6 * top).max(1e-6);
    let vals = eig.eigenvalues.map(|v| v.abs().max(floor));
    &eig.eigenvectors * DMatrix::from_diagonal(&vals) * eig.eigenvectors.transpose()
}

#[cfg(test)]
mod tests {
    use super::gate::GATE_RATIO;
    use super::*;
    use crate::estimate::ml::estimate_by;

    /// `−log L` of `x` ~ N(0, θ₁) and `y` ~ N(0, θ₁ + θ₂), `n` of each, with sample
    /// second moments `sx`, `sy`: θ₂ is a nuisance of θ₁'s profile only through the sum.
    fn two_variances(n: f64, sx: f64, sy: f64) -> impl Fn(&[f64]) -> Option<f64> {
        move |t: &[f64]| {
            let (a, b) = (t[0], t[0] + t[1]);
            (a > 0.0 && b > 0.0).then(|| 0.5 * n * (a.ln() + sx / a) + 0.5 * n * (b.ln() + sy / b))
        }
    }

    /// The profile of θ_i by brute force: a fine grid in the other parameter's log, then
    /// golden-section refinement (written apart from the traced profile).
    fn brute_profile(nll: &dyn Fn(&[f64]) -> Option<f64>, i: usize, v: f64) -> f64 {
        let at = |u: f64| {
            let mut t = [0.0; 2];
            t[i] = v;
            t[1 - i] = u.exp();
            nll(&t).unwrap_or(f64::INFINITY)
        };
        let grid: Vec<f64> = (0..4000).map(|k| -20.0 + k as f64 * 0.01).collect();
        let k = (0..grid.len())
            .min_by(|&a, &b| at(grid[a]).total_cmp(&at(grid[b])))
            .unwrap();
        let (mut lo, mut hi) = (grid[k.saturating_sub(1)], grid[(k + 1).min(grid.len() - 1)]);
        let g = 0.5 * (5f64.sqrt() - 1.0);
        for _ in 0..100 {
            let (c, d) = (hi - g * (hi - lo), lo + g * (hi - lo));
            if at(c) < at(d) {
                hi = d;
            } else {
                lo = c;
            }
        }
        at(0.5 * (lo + hi))
    }

    /// Each traced end of both parameters' intervals lies where the brute-force profile is
    /// `c` nats above the minimum, to within [`END_TOL`] plus the brute force's own error;
    /// an end at 0 only where the profile at zero is within `c`.
    #[test]
    fn traced_ends_sit_where_the_profile_crosses_its_level() {
        let mut zeros = 0;
        for &(n, sx, sy) in &[(40.0, 1.0, 3.0), (200.0, 2.0, 2.5), (15.0, 0.3, 9.0)] {
            let nll = two_variances(n, sx, sy);
            let est = estimate_by(&nll, 2 * n as usize, &[1.0, 1.0], &[false, false], 200)
                .expect("the search runs");
            assert!(est.converged && est.at_bound.is_empty(), "{est:?}");
            let r = likelihood_ranges(&nll, &est, &[false, false], 0.95);
            let c = 0.5 * chi2_inv(0.95, 1.0);
            for i in 0..2 {
                let range = r.ranges[i].expect("traced");
                for end in [range.lower, range.upper] {
                    assert!(end.reached, "{n} {sx} {sy}: {range:?}");
                    if end.value == 0.0 {
                        let rise = brute_profile(&nll, i, 1e-12) - est.neg_log_likelihood;
                        assert!(rise < c, "θ{i} = 0 is {rise} nats up");
                        continue;
                    }
                    let rise = brute_profile(&nll, i, end.value) - est.neg_log_likelihood;
                    assert!(
                        (rise - c).abs() < END_TOL + 1e-6,
                        "n {n}, θ{i} end {}: the profile rises {rise}, not {c}",
                        end.value
                    );
                }
                assert!(range.lower.value < est.theta[i] && est.theta[i] < range.upper.value);
                zeros += usize::from(range.lower.value == 0.0);
            }
        }
        // (200, 2, 2.5): θ₂ = 0 is 1.24 nats up, inside the level, so one lower end is 0.
        assert_eq!(zeros, 1);
    }

    /// A parameter the data put at zero (y's spread below x's): its interval starts at 0,
    /// and its upper end is the one-sided level's, χ²₁(0.90)/2 nats up.
    #[test]
    fn a_parameter_at_its_bound_starts_at_zero_with_the_one_sided_level() {
        let nll = two_variances(100.0, 2.0, 1.6);
        let est = estimate_by(&nll, 200, &[1.0, 1.0], &[false, false], 200).unwrap();
        assert_eq!(est.at_bound, vec![1], "{est:?}");
        let r = likelihood_ranges(&nll, &est, &[false, false], 0.95);
        let range = r.ranges[1].expect("traced");
        assert_eq!(range.lower.value, 0.0);
        assert!(range.lower.reached && range.upper.reached, "{range:?}");
        let rise = brute_profile(&nll, 1, range.upper.value) - est.neg_log_likelihood;
        let c = 0.5 * chi2_inv(0.90, 1.0);
        assert!((rise - c).abs() < END_TOL + 1e-6, "rise {rise}, not {c}");
    }

    /// A parameter the likelihood does not bound above (it enters only through a term the
    /// data do not see) is traced to the limit and said to reach beyond it.
    #[test]
    fn an_unbounded_side_is_said_to_reach_beyond_the_trace() {
        let nll = |t: &[f64]| Some(50.0 * (t[0].ln() + 1.0 / t[0]) + 1e-9 * t[1].ln());
        let est = estimate_by(&nll, 100, &[1.0, 1.0], &[false, false], 200).unwrap();
        let r = likelihood_ranges(&nll, &est, &[false, false], 0.95);
        let free = r.ranges[1].expect("traced");
        assert!(!free.upper.reached && free.upper.value >= 0.99e4 * est.theta[1]);
        assert!(free.contains(1e9 * est.theta[1]));
        assert!(r.ranges[0].expect("traced").upper.reached);
    }

    /// The gate's range along each parameter ends within the last bracket's ratio of where
    /// the pass region ends, and a side that passes past ×10³ is open.
    #[test]
    fn gate_ranges_find_where_passing_stops() {
        let passes = |t: &[f64]| Some((0.3..=2.0).contains(&t[0]) && t[1] <= 7.0);
        let g = gate_ranges(&passes, &[1.0, 1.0, 5.0], &[false, false, true]);
        assert!(g.passes_at_point);
        let a = g.ranges[0].unwrap();
        assert!(a.lower.reached && a.lower.value >= 0.3 && a.lower.value < 0.3 * GATE_RATIO);
        assert!(a.upper.reached && a.upper.value <= 2.0 && a.upper.value > 2.0 / GATE_RATIO);
        let b = g.ranges[1].unwrap();
        assert!(!b.lower.reached && b.lower.value <= 1e-3 * 1.0001);
        assert!(b.upper.reached && b.upper.value > 7.0 / GATE_RATIO);
        assert!(g.ranges[2].is_none());
        let failing = gate_ranges(&passes, &[5.0, 1.0, 5.0], &[false, false, true]);
        assert!(!failing.passes_at_point && failing.ranges.iter().all(Option::is_none));
    }
}
