//! A search's plan before it starts: the local search an unset choice resolves to, the
//! evaluations it is expected to take, and the notes a user should read first (a budget
//! that cannot be enough).

use super::choices::LocalSearch;
use super::settings::TuneSettings;

impl TuneSettings {
    /// Evaluations the search is expected to spend with local search `local` on `dim` free
    /// parameters: the global stage's 1 + points · d, then per local search about 50 d for
    /// the simplex (Nelder–Mead and its polish, measured on 2- to 4-parameter problems:
    /// 386 evaluations for 4 searches in 2-D) and 12 (d + 1) for Gauss–Newton (two
    /// Levenberg–Marquardt solves of a few iterations of d + 1 evaluations each). The
    /// simplex runs one more search from the winner. A projection, not a bound.
    pub fn projected_evaluations(&self, local: LocalSearch, dim: usize) -> usize {
        let global = if self.from_estimate {
            0
        } else {
            1 + self.global_points.saturating_mul(dim)
        };
        let starts = if self.from_estimate { 1 } else { self.starts };
        let local_evals = match local {
            LocalSearch::Simplex => (starts + 1).saturating_mul(50 * dim),
            LocalSearch::GaussNewton => starts.saturating_mul(12 * (dim + 1)),
        };
        global.saturating_add(local_evals)
    }

    /// The search's plan for an experiment whose evaluation takes `seconds_per_eval` s, with
    /// `dim` free parameters, `targets` when every one of them declares the components it
    /// drives (so Gauss–Newton can solve the moment equations), and `exact` scoring.
    ///
    /// An unset local search is the problem's: Gauss–Newton under Monte Carlo scoring when
    /// every free parameter declares the components it drives (the moment equations then
    /// give each parameter its own equation, and each Levenberg–Marquardt iteration costs
    /// d + 1 evaluations where the simplex takes about 50 d a search: 90 evaluations
    /// instead of 239 on the catalog's ctrv, to the same values within the search's Monte
    /// Carlo noise); the simplex otherwise: exact scoring, and Monte Carlo scoring on one
    /// record (`seed_free`), are noise-free, cheap and want J's own minimum to the last
    /// digit, and without targets only J's residuals are left. Whatever the method, a plan whose
    /// projected time exceeds the budget says so, with the budget to set.
    pub fn plan(
        &self,
        dim: usize,
        targets: bool,
        exact: bool,
        seed_free: bool,
        seconds_per_eval: f64,
    ) -> Plan {
        let seconds = |n: usize| n as f64 * seconds_per_eval;
        let gauss_newton = !self.local_set
            && self.local == LocalSearch::Simplex
            && !exact
            && !seed_free
            && targets
            && dim > 0;
        let local = if gauss_newton {
            LocalSearch::GaussNewton
        } else {
            self.local
        };
        let projected = self.projected_evaluations(local, dim);
        let mut notes = Vec::new();
        let evals = projected.min(self.max_evals);
        if dim > 0 && !exact && seconds(evals) > self.max_seconds {
            // Twice the projection, rounded up to a minute: projections are rough.
            let want = (2.0 * seconds(projected) / 60.0).ceil() * 60.0;
            notes.push(format!(
                "each evaluation takes {}: the search needs ~{projected} evaluations (~{}), more than max_seconds = {}; set --max-seconds {want} (or [tune] max_seconds){}",
                fmt_seconds(seconds_per_eval),
                fmt_seconds(seconds(projected)),
                self.max_seconds,
                if local == LocalSearch::Simplex && targets {
                    ", or --local gauss_newton"
                } else {
                    ""
                },
            ));
        }
        Plan {
            local,
            projected,
            notes,
        }
    }
}

/// A search plan: the local search chosen and what it is expected to cost
/// ([`TuneSettings::plan`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// The local search to run.
    pub local: LocalSearch,
    /// Evaluations the search is expected to take.
    pub projected: usize,
    /// One line for each thing the user should know before the search: a method chosen
    /// for them, a budget that cannot be enough.
    pub notes: Vec<String>,
}

/// A duration for a one-line note: `0.31 s`, `95 s`, `12 min`.
fn fmt_seconds(s: f64) -> String {
    if s < 10.0 {
        format!("{s:.2} s")
    } else if s < 600.0 {
        format!("{s:.0} s")
    } else {
        format!("{:.0} min", s / 60.0)
    }
}
