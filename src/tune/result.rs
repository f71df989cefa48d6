//! What a tuning run hands back: the result, its status, the per-parameter resolution, and
//! the observer that watches it run.

use serde::Serialize;

use super::choices::{LocalSearch, Scoring};
use super::objective::Terms;
use crate::stats::ConsistencyReport;

/// How a tuning run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TuneStatus {
    /// The tuned filter passed the gate on fresh seeds as often as a consistent filter does
    /// (its count inside the binomial band).
    Consistent,
    /// The search finished but the tuned filter fails the gate on fresh seeds more often
    /// than a consistent filter: no value of the free parameters makes it consistent.
    Inconsistent,
    /// The search did not converge (the best point so far is reported): the budget ran
    /// out, or a parameter ended on a bound that had already been widened once (the box,
    /// not the data, stopped it) and the tuned filter fails the confirmation.
    BudgetExhausted,
    /// No candidate gave a filter that stayed positive definite.
    Diverged,
    /// The tuned filter fails its confirmation, but the evidence does not establish that
    /// no value fits: the searches from several starts in a widened box disagree on the
    /// best score, or the best point passes the gate on more runs (an effect at the limit
    /// of N runs). See the run's certificate.
    Undecided,
}

/// How precisely the data pin down one parameter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Resolution {
    /// The factor within which the gate's N runs determine the parameter (two standard
    /// deviations of the estimate they would give, others re-adjusting); `None` if fixed.
    pub factor: Option<f64>,
    /// False when that factor exceeds 2 (a flat direction of the objective) or the value
    /// sits on a search bound (the data might want it beyond).
    pub identifiable: bool,
    /// The tuned value is within 5% of its lower or upper search bound.
    pub at_bound: bool,
}

impl Resolution {
    /// A parameter held fixed: nothing to resolve.
    pub const FIXED: Resolution = Resolution {
        factor: None,
        identifiable: true,
        at_bound: false,
    };
}

/// A search bound that the tuner widened once because a free parameter ended on it
/// (see [`super::tune`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Widening {
    /// The parameter's index (problem order).
    pub param: usize,
    /// Its bounds before, (lower, upper), in the parameter's units.
    pub from: (f64, f64),
    /// Its bounds after, (lower, upper), in the parameter's units.
    pub to: (f64, f64),
}

/// Observes a tuning run (progress bars, logs). All methods default to doing nothing.
pub trait Observer: Sync {
    /// Called after each evaluation with the count so far and the best objective value.
    /// Evaluations that ran in parallel are reported when they are booked, in a fixed order.
    fn evaluation(&self, _evals: usize, _best: f64) {}
    /// Called when a phase starts ("global", "local", "confirm").
    fn phase(&self, _name: &str) {}
    /// Called before the search with one line the user should read: a local search chosen
    /// from the measured cost of an evaluation, or a budget that cannot be enough.
    fn note(&self, _line: &str) {}
}

/// An observer that does nothing.
pub struct Silent;

impl Observer for Silent {}

/// How the tuned filter fared on fresh seeds.
#[derive(Debug, Clone, Serialize)]
pub struct Confirmation {
    /// The first seed; seed k is `first_seed + k`.
    pub first_seed: u64,
    /// Number of fresh seeds K.
    pub seeds: usize,
    /// How many passed the gate.
    pub passed: usize,
    /// The fewest passes a consistent filter gives with probability at least 99%: the
    /// lower end of the binomial band of K seeds at a pass rate of 1 − α.
    pub band_low: usize,
    /// The experiment is one recorded data set ([`crate::experiment::Sampling::seed_free`]):
    /// the gate ran once on it, and it must pass.
    pub recorded: bool,
}

impl Confirmation {
    /// Whether the count lies in the band of a consistent filter.
    pub fn holds(&self) -> bool {
        self.passed >= self.band_low
    }

    /// "19 of 20 fresh seeds pass (a consistent filter passes ≥ 16 with 99% probability)".
    pub fn text(&self) -> String {
        if self.recorded {
            let how = if self.passed == 1 { "pass" } else { "fail" };
            return format!(
                "the recorded measurements {how} the gate (recorded data, judged as they are: no fresh seeds to confirm on)"
            );
        }
        format!(
            "{} of {} fresh seeds pass the gate (a consistent filter passes at least {} with 99% probability)",
            self.passed, self.seeds, self.band_low
        )
    }
}

/// One start's search in the widened box.
#[derive(Debug, Clone, Serialize)]
pub struct CertifiedStart {
    /// The start (problem order).
    pub start: Vec<f64>,
    /// Where its search ended.
    pub tuned: Vec<f64>,
    /// The objective there.
    pub score: f64,
    /// Fresh seeds its tuned filter passed, of those tried.
    pub passed: usize,
    /// Fresh seeds tried.
    pub seeds: usize,
    /// How its search ended.
    pub status: TuneStatus,
    /// Evaluations its search spent.
    pub evaluations: usize,
    /// Evaluations its refinement spent.
    pub refine_evaluations: usize,
    /// Its wall-clock time, s.
    pub seconds: f64,
}

/// What the certification of a misfit found.
#[derive(Debug, Clone, Serialize)]
pub struct Certificate {
    /// The widened box, (lower, upper) per parameter (fixed ones as they were).
    pub bounds: Vec<(f64, f64)>,
    /// Each start's search, the first search's result first.
    pub starts: Vec<CertifiedStart>,
    /// Starts whose score agrees with the best one's.
    pub agreeing: usize,
    /// Runs of the recheck at the best point.
    pub recheck_runs: usize,
    /// Whether the best point passed the gate on the recheck (a misfit at the limit of N
    /// runs); `None` when no recheck ran (a start fit).
    pub recheck_passed: Option<bool>,
    /// Whether the misfit is proven.
    pub proven: bool,
}

/// Everything a tuning run found.
#[derive(Debug, Clone, Serialize)]
pub struct TuneResult {
    /// Parameter names, in problem order.
    pub names: Vec<String>,
    /// Which parameters were held fixed.
    pub fixed: Vec<bool>,
    /// Starting values.
    pub initial: Vec<f64>,
    /// Tuned values.
    pub tuned: Vec<f64>,
    /// Objective at the start (as scored in the search).
    pub objective_initial: Terms,
    /// Objective at the tuned values.
    pub objective_final: Terms,
    /// How candidates were scored.
    pub scoring: Scoring,
    /// The local search that ran: the one set, or the one chosen from the measured cost of
    /// an evaluation ([`super::TuneSettings::plan`]).
    pub local: LocalSearch,
    /// Evaluations spent by the search.
    pub evaluations: usize,
    /// Candidates whose filter diverged.
    pub diverged_evaluations: usize,
    /// Best objective after each evaluation (for plots), in an order that does not depend
    /// on the thread count: evaluations that ran in parallel are booked in the order of
    /// their points or starts.
    pub history: Vec<f64>,
    /// Resolution per parameter; `None` when not assessed because the budget ran out (the
    /// curvature says something only at a converged optimum, and measuring it would spend
    /// evaluations the budget no longer has).
    pub resolution: Option<Vec<Resolution>>,
    /// Per parameter, whether its tuned value lies within 5% (0.05 in log units) of a
    /// bound of the box it was last searched in (the widened one, if it was widened);
    /// assessed whatever the status, a run that stopped on its budget included. Fixed
    /// parameters: false.
    pub at_bound: Vec<bool>,
    /// The bounds widened once (log space) because a free parameter ended on them after a
    /// converged search, each followed by one more local search; empty when none was.
    pub widened: Vec<Widening>,
    /// Whether the search ran block by block over the experiment's decoupled blocks
    /// ([`crate::experiment::Structure::blocks`]) rather than on the pooled objective.
    pub separable: bool,
    /// Evaluations of the refinement (the gate's sensitivity and the refinement's steps),
    /// beside the search's budget.
    pub refine_evaluations: usize,
    /// Seed used for the search's Monte Carlo runs (common random numbers).
    pub search_seed: u64,
    /// Seed of the first confirmation run.
    pub confirm_seed: u64,
    /// The gate on fresh seeds: how many of them the tuned filter passes.
    pub confirmation: super::Confirmation,
    /// Monte Carlo settings of the confirmation.
    pub runs: usize,
    /// Steps of the confirmation.
    pub steps: usize,
    /// Significance level.
    pub alpha: f64,
    /// The starting filter on the first confirmation seed.
    pub before: ConsistencyReport,
    /// The tuned filter on the first confirmation seed.
    pub after: ConsistencyReport,
    /// How the run ended.
    pub status: TuneStatus,
    /// On one record that passes the gate at the tuned values: the range along each free
    /// parameter (the others at their tuned values) over which the record still passes.
    /// One record has no seed-to-seed spread, so this stands where a resolution would.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub supported: Option<crate::estimate::GateRanges>,
    /// The certification of a misfit (searches from several starts in a widened box, the
    /// best point rechecked on more runs), where the run needed one; absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub certificate: Option<super::certify::Certificate>,
    /// Where the truth of each evaluation came from: replayed from tapes, or simulated at
    /// every one and why.
    pub truth: crate::experiment::TruthReuse,
    /// Wall time of the search and confirmation, s. Not serialized: a report of the same
    /// run must be the same file every time (the command line prints it on stdout).
    #[serde(skip_serializing)]
    pub seconds: f64,
}
