//! The tuner's settings, checked where they are set.

use super::choices::{LocalSearch, Scoring};
use super::objective::Weights;
use crate::input::{SettingError, at_least, at_most};
use crate::montecarlo::MAX_RUNS;

/// Largest wall-time budget, s: 10⁹ s, about 32 years. The search's deadline is the start
/// time plus this budget, and that sum must be representable: `Duration::from_secs_f64`
/// panics above 2⁶⁴ s and adding a `Duration` to an `Instant` overflows above about
/// 2⁶³ s less the clock's own value. A billion seconds is far inside both and longer than
/// any search.
pub const MAX_SECONDS: f64 = 1e9;

/// Largest number of quasi-random points of the global stage per free parameter: 1000
/// (the default is 16). The stage builds all of its 1 + points·d candidates of d
/// coordinates before scoring them, so this bounds its memory (about 80 MB for 100 free
/// parameters) whatever the evaluation budget; the budget itself stops the scoring, and
/// more points than it can score would only be built to be thrown away.
pub const MAX_GLOBAL_POINTS: usize = 1000;

/// Search settings. Every value is checked by its setter:
///
/// ```
/// use autotune::{LocalSearch, TuneSettings};
/// let s = TuneSettings::default()
///     .with_max_evals(500)?
///     .with_local(LocalSearch::GaussNewton)
///     .with_weight("shape", 1.0)?;
/// assert_eq!(s.max_evals(), 500);
/// assert!(TuneSettings::default().with_starts(0).is_err());
/// # Ok::<(), autotune::SettingError>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct TuneSettings {
    pub(super) weights: Weights,
    pub(super) nis_only: bool,
    pub(super) max_evals: usize,
    pub(super) max_seconds: f64,
    pub(super) starts: usize,
    pub(super) global_points: usize,
    pub(super) scoring: Scoring,
    pub(super) local: LocalSearch,
    pub(super) local_set: bool,
    pub(super) confirm_seed: Option<u64>,
    pub(super) search_runs: Option<usize>,
    pub(super) confirm_seeds: usize,
    pub(super) refine_runs: Option<usize>,
    pub(super) from_estimate: bool,
    pub(super) certify: bool,
    pub(super) stop_below: f64,
}

impl Default for TuneSettings {
    fn default() -> Self {
        TuneSettings {
            weights: Weights::default(),
            nis_only: false,
            max_evals: 4000,
            max_seconds: 120.0,
            starts: 3,
            global_points: 16,
            scoring: Scoring::Auto,
            local: LocalSearch::Simplex,
            local_set: false,
            confirm_seed: None,
            search_runs: None,
            confirm_seeds: 20,
            refine_runs: None,
            from_estimate: false,
            certify: true,
            stop_below: 0.0,
        }
    }
}

impl TuneSettings {
    /// Objective weights, each finite and ≥ 0 and not all 0 (J would then be 0 for every
    /// candidate).
    pub fn with_weights(mut self, weights: Weights) -> Result<Self, SettingError> {
        weights.check_not_all_zero()?;
        self.weights = weights;
        Ok(self)
    }

    /// One objective weight by name (`mean`, `interval`, `per_step`, `components`,
    /// `whiteness`, `shape`), finite and ≥ 0; the weights may not all be 0 afterwards. To
    /// zero every default weight but one, set that one first, or use
    /// [`TuneSettings::with_named_weights`].
    pub fn with_weight(self, name: &str, value: f64) -> Result<Self, SettingError> {
        self.with_named_weights([(name, value)])
    }

    /// Several objective weights by name, as a problem file's `[tune.weights]` or repeated
    /// `--weight` flags give them, set together: each is checked as by
    /// [`TuneSettings::with_weight`], and only the result must not be all 0.
    pub fn with_named_weights<'a>(
        self,
        weights: impl IntoIterator<Item = (&'a str, f64)>,
    ) -> Result<Self, SettingError> {
        let mut w = self.weights;
        for (name, value) in weights {
            w.set(name, value)?;
        }
        self.with_weights(w)
    }

    /// Score NIS and measurement statistics only (no trusted ground truth).
    pub fn with_nis_only(mut self, nis_only: bool) -> Self {
        self.nis_only = nis_only;
        self
    }

    /// Evaluation budget of the search (≥ 1).
    pub fn with_max_evals<N: TryInto<usize> + std::fmt::Display + Copy>(
        mut self,
        n: N,
    ) -> Result<Self, SettingError> {
        self.max_evals = at_least("max_evals", n, 1)?;
        Ok(self)
    }

    /// Wall-time budget of the search, s (finite, > 0 and ≤ `MAX_SECONDS`, 10⁹ s).
    pub fn with_max_seconds(mut self, s: f64) -> Result<Self, SettingError> {
        if !(s.is_finite() && s > 0.0) {
            return Err(SettingError::new("max_seconds", format!("{s} must be > 0")));
        }
        if s > MAX_SECONDS {
            return Err(SettingError::new(
                "max_seconds",
                format!("{s:e} must be ≤ {MAX_SECONDS:e} (about 32 years)"),
            ));
        }
        self.max_seconds = s;
        Ok(self)
    }

    /// Number of local searches, started from the best points of the global stage (≥ 1).
    pub fn with_starts<N: TryInto<usize> + std::fmt::Display + Copy>(
        mut self,
        n: N,
    ) -> Result<Self, SettingError> {
        self.starts = at_least("starts", n, 1)?;
        Ok(self)
    }

    /// Quasi-random points of the global stage per free parameter, in
    /// 1..=`MAX_GLOBAL_POINTS` (1000).
    pub fn with_global_points<N: TryInto<usize> + std::fmt::Display + Copy>(
        mut self,
        n: N,
    ) -> Result<Self, SettingError> {
        let n = at_least("global_points", n, 1)?;
        self.global_points = at_most("global_points", n, MAX_GLOBAL_POINTS)?;
        Ok(self)
    }

    /// How candidates are scored.
    pub fn with_scoring(mut self, scoring: Scoring) -> Self {
        self.scoring = scoring;
        self
    }

    /// The local search.
    /// Whether the start is an estimate close to the answer (`tune --init`): the search then
    /// skips the global stage and runs one local search from the start, with a first simplex
    /// of ±20% instead of a factor 2.
    pub fn with_from_estimate(mut self, from_estimate: bool) -> Self {
        self.from_estimate = from_estimate;
        self
    }

    /// Whether the start is an estimate (see [`TuneSettings::with_from_estimate`]).
    pub fn from_estimate(&self) -> bool {
        self.from_estimate
    }

    /// Set the local search. Unset, the tuner chooses it from the experiment's measured
    /// cost (see [`TuneSettings::plan`]).
    pub fn with_local(mut self, local: LocalSearch) -> Self {
        self.local = local;
        self.local_set = true;
        self
    }

    /// Whether the local search was set (by a problem file, a flag or
    /// [`TuneSettings::with_local`]) rather than left to the tuner.
    pub fn local_is_set(&self) -> bool {
        self.local_set
    }
}

impl TuneSettings {
    /// Whether a run whose tuned filter fails its confirmation certifies the misfit before
    /// claiming it (the default): searches from several starts in a widened box, the best
    /// point rechecked on more runs (`tune::certify`). Off for the searches inside a
    /// certification and inside an explanation's trials.
    pub fn with_certify(mut self, certify: bool) -> Self {
        self.certify = certify;
        self
    }

    /// Stop the search once its score is below `j` (0, the default: search until it
    /// converges): for a search that only asks whether some value fits, as an explanation's
    /// trial does. Values that are not finite or are negative are taken as 0.
    pub fn with_stop_below(mut self, j: f64) -> Self {
        self.stop_below = if j.is_finite() { j.max(0.0) } else { 0.0 };
        self
    }

    /// The score below which the search stops ([`TuneSettings::with_stop_below`]).
    pub fn stop_below(&self) -> f64 {
        self.stop_below
    }

    /// Whether misfits are certified ([`TuneSettings::with_certify`]).
    pub fn certify(&self) -> bool {
        self.certify
    }

    /// Seed of the confirmation runs (`None`: derived from the search seed, never equal).
    pub fn with_confirm_seed(mut self, seed: Option<u64>) -> Self {
        self.confirm_seed = seed;
        self
    }

    /// Runs per Monte Carlo evaluation in the search, in 1..=`MAX_RUNS` (the Monte Carlo
    /// test's own bound; default 4 N, see [`TuneSettings::search_runs_for`]).
    pub fn with_search_runs<N: TryInto<usize> + std::fmt::Display + Copy>(
        mut self,
        n: N,
    ) -> Result<Self, SettingError> {
        let n = at_least("search_runs", n, 1)?;
        self.search_runs = Some(at_most("search_runs", n, MAX_RUNS)?);
        Ok(self)
    }

    /// Objective weights.
    pub fn weights(&self) -> Weights {
        self.weights
    }

    /// Whether only innovations are scored.
    pub fn nis_only(&self) -> bool {
        self.nis_only
    }

    /// Whether the estimation errors are scored (NEES and the state components) on an
    /// experiment that has states (`has_states`: ground truth to score against), or only the
    /// innovations.
    pub fn scores_nees(&self, has_states: bool) -> bool {
        !self.nis_only && has_states
    }

    /// Evaluation budget.
    pub fn max_evals(&self) -> usize {
        self.max_evals
    }

    /// Wall-time budget, s.
    pub fn max_seconds(&self) -> f64 {
        self.max_seconds
    }

    /// Number of local searches.
    pub fn starts(&self) -> usize {
        self.starts
    }

    /// Global-stage points per free parameter.
    pub fn global_points(&self) -> usize {
        self.global_points
    }

    /// How candidates are scored.
    pub fn scoring(&self) -> Scoring {
        self.scoring
    }

    /// The local search.
    pub fn local(&self) -> LocalSearch {
        self.local
    }

    /// Number of fresh seeds K of the confirmation (2 to 10,000; default 20): the tuned
    /// filter is consistent when its pass count lies in the binomial band of a filter that
    /// passes each with probability 1 − α.
    pub fn with_confirm_seeds<N: TryInto<usize> + std::fmt::Display + Copy>(
        mut self,
        n: N,
    ) -> Result<Self, SettingError> {
        let k = at_least("confirm_seeds", n, 2)?;
        if k > 10_000 {
            return Err(SettingError::new(
                "confirm_seeds",
                format!("{k} is more than 10000 confirmation seeds"),
            ));
        }
        self.confirm_seeds = k;
        Ok(self)
    }

    /// Number of fresh seeds of the confirmation.
    pub fn confirm_seeds(&self) -> usize {
        self.confirm_seeds
    }

    /// Runs of the final refinement under Monte Carlo scoring, in 1..=`MAX_RUNS` (the Monte
    /// Carlo test's own bound; default four times the search's runs).
    pub fn with_refine_runs<N: TryInto<usize> + std::fmt::Display + Copy>(
        mut self,
        n: Option<N>,
    ) -> Result<Self, SettingError> {
        self.refine_runs = match n {
            Some(n) => Some(at_most(
                "refine_runs",
                at_least("refine_runs", n, 1)?,
                MAX_RUNS,
            )?),
            None => None,
        };
        Ok(self)
    }

    /// Runs of the final refinement, if set.
    pub fn refine_runs(&self) -> Option<usize> {
        self.refine_runs
    }

    /// Seed of the confirmation runs, if set.
    pub fn confirm_seed(&self) -> Option<u64> {
        self.confirm_seed
    }

    /// Runs per Monte Carlo evaluation in the search, if set (default 4 N: a parameter
    /// estimated from N runs is as noisy as the N-run gate that confirms it, so the
    /// confirmation would fail far more often than α; four times the runs halve the noise).
    pub fn search_runs(&self) -> Option<usize> {
        self.search_runs
    }

    /// Runs per Monte Carlo evaluation in the search for a confirmation of `runs` runs: the
    /// set value, or 4 `runs` computed without overflow and refused above `MAX_RUNS`
    /// (the error's setting is `runs`, whose value is too large for the default).
    pub fn search_runs_for(&self, runs: usize) -> Result<usize, SettingError> {
        match self.search_runs {
            Some(n) => Ok(n),
            None => runs
                .checked_mul(4)
                .filter(|&n| n <= MAX_RUNS)
                .ok_or_else(|| {
                    SettingError::new(
                        "runs",
                        format!(
                            "{runs} must be ≤ {} for the search's default 4 N runs (or set search_runs)",
                            MAX_RUNS / 4
                        ),
                    )
                }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plan_is_gauss_newton_on_noisy_scoring_with_targets_and_the_simplex_otherwise() {
        let s = TuneSettings::default();
        // (dim, targets, exact, seed_free): only Monte Carlo scoring on seeds, with targets
        // and something to search, takes Gauss–Newton; an evaluation's cost does not matter.
        for seconds in [1e-4, 0.01] {
            assert_eq!(
                s.plan(2, true, false, false, seconds).local,
                LocalSearch::GaussNewton
            );
        }
        for (dim, targets, exact, seed_free) in [
            (2, true, true, false),
            (2, true, false, true),
            (2, false, false, false),
            (0, true, false, false),
        ] {
            let plan = s.plan(dim, targets, exact, seed_free, 1e-4);
            assert_eq!(
                plan.local,
                LocalSearch::Simplex,
                "{dim} {targets} {exact} {seed_free}"
            );
        }
        // A method set is kept, whichever.
        let set = s.clone().with_local(LocalSearch::Simplex);
        assert_eq!(
            set.plan(2, true, false, false, 1e-4).local,
            LocalSearch::Simplex
        );
        let set = s.clone().with_local(LocalSearch::GaussNewton);
        assert_eq!(
            set.plan(2, true, true, false, 1e-4).local,
            LocalSearch::GaussNewton
        );
    }

    #[test]
    fn a_plan_past_the_time_budget_says_so_with_the_budget_to_set() {
        let s = TuneSettings::default();
        // Gauss–Newton in 2-D: 1 + 16 · 2 global points and 3 starts of 12 · 3: 141
        // evaluations. At 0.1 ms each (14 ms) no note; at 1 s each 141 s > 120 s, and twice
        // that rounded up to a minute is 300 s.
        let cheap = s.plan(2, true, false, false, 1e-4);
        assert_eq!(cheap.projected, 141);
        assert!(cheap.notes.is_empty(), "{:?}", cheap.notes);
        let slow = s.plan(2, true, false, false, 1.0);
        assert_eq!(
            slow.notes,
            [
                "each evaluation takes 1.00 s: the search needs ~141 evaluations (~141 s), more \
              than max_seconds = 120; set --max-seconds 300 (or [tune] max_seconds)"
            ]
        );
        // The simplex, set, in 2-D: 33 + 4 · 100 = 433 evaluations; with targets the note
        // names the faster method too. Exact scoring is never timed against the budget.
        let simplex = s.clone().with_local(LocalSearch::Simplex);
        let plan = simplex.plan(2, true, false, false, 1.0);
        assert_eq!(plan.projected, 433);
        assert!(
            plan.notes[0].ends_with(
                "set --max-seconds 900 (or [tune] max_seconds), or --local gauss_newton"
            ),
            "{:?}",
            plan.notes
        );
        assert!(simplex.plan(2, true, true, false, 1.0).notes.is_empty());
    }

    #[test]
    fn setters_accept_valid_and_refuse_invalid_values() {
        let s = TuneSettings::default();
        assert_eq!(s.clone().with_max_evals(7).unwrap().max_evals(), 7);
        assert_eq!(
            s.clone().with_max_evals(0).unwrap_err(),
            SettingError::new("max_evals", "0 must be ≥ 1")
        );
        assert_eq!(
            s.clone().with_max_evals(-2_i64).unwrap_err(),
            SettingError::new("max_evals", "-2 must be ≥ 1")
        );
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert_eq!(
                s.clone().with_max_seconds(bad).unwrap_err().setting,
                "max_seconds"
            );
        }
        assert_eq!(s.clone().with_max_seconds(0.5).unwrap().max_seconds(), 0.5);
        assert!(s.clone().with_starts(0).is_err());
        assert_eq!(s.clone().with_starts(2).unwrap().starts(), 2);
        assert!(s.clone().with_global_points(0).is_err());
        assert_eq!(s.clone().with_global_points(3).unwrap().global_points(), 3);
        assert_eq!(
            s.clone().with_max_seconds(1e19).unwrap_err(),
            SettingError::new("max_seconds", "1e19 must be ≤ 1e9 (about 32 years)")
        );
        assert_eq!(
            s.clone()
                .with_max_seconds(MAX_SECONDS)
                .unwrap()
                .max_seconds(),
            1e9
        );
        assert_eq!(
            s.clone().with_global_points(i64::MAX).unwrap_err(),
            SettingError::new("global_points", "9223372036854775807 must be ≤ 1000")
        );
        assert!(s.clone().with_search_runs(0).is_err());
        assert_eq!(
            s.clone()
                .with_refine_runs(Some(i64::MAX))
                .unwrap_err()
                .setting,
            "refine_runs"
        );
        assert_eq!(
            s.clone().with_search_runs(u64::MAX).unwrap_err().setting,
            "search_runs"
        );
        assert_eq!(s.search_runs_for(10), Ok(40));
        assert_eq!(s.search_runs_for(usize::MAX).unwrap_err().setting, "runs");
        assert_eq!(
            s.clone()
                .with_search_runs(7)
                .unwrap()
                .search_runs_for(usize::MAX),
            Ok(7)
        );
        assert_eq!(
            s.clone().with_search_runs(9).unwrap().search_runs(),
            Some(9)
        );
        assert_eq!(
            s.clone().with_weight("colour", 1.0).unwrap_err().setting,
            "weights.colour"
        );
        assert!(s.clone().with_weight("shape", -1.0).is_err());
        assert_eq!(
            s.clone().with_weight("shape", 2.0).unwrap().weights().shape,
            2.0
        );
        // All-zero weights make every candidate score 0; zeroing all but shape works when
        // the weights are set together, whatever their order.
        let zeros = ["mean", "interval", "per_step", "components", "whiteness"].map(|n| (n, 0.0));
        assert_eq!(
            s.clone().with_named_weights(zeros).unwrap_err().setting,
            "weights"
        );
        let only_shape = zeros.into_iter().chain([("shape", 1.0)]);
        assert_eq!(
            s.clone()
                .with_named_weights(only_shape)
                .unwrap()
                .weights()
                .shape,
            1.0
        );
        assert_eq!(
            s.clone().with_weights(Weights::ZERO).unwrap_err().setting,
            "weights"
        );
    }

    #[test]
    fn names_and_aliases_parse_and_unknown_names_list_the_known_ones() {
        assert_eq!(
            Scoring::from_name("monte-carlo").unwrap(),
            Scoring::MonteCarlo
        );
        assert_eq!(Scoring::from_name("exact").unwrap(), Scoring::Exact);
        assert_eq!(
            Scoring::from_name("x").unwrap_err().message,
            "unknown scoring 'x' (known: auto, exact, monte_carlo)"
        );
        assert_eq!(
            LocalSearch::from_name("levenberg_marquardt").unwrap(),
            LocalSearch::GaussNewton
        );
        assert_eq!(
            LocalSearch::from_name("nelder-mead").unwrap(),
            LocalSearch::Simplex
        );
        assert_eq!(
            LocalSearch::from_name("newton").unwrap_err(),
            SettingError::new(
                "local",
                "unknown local search 'newton' (known: simplex, gauss_newton)"
            )
        );
    }

    #[test]
    fn errors_are_scored_only_with_states_and_not_nis_only() {
        let s = TuneSettings::default();
        assert!(s.scores_nees(true));
        assert!(!s.scores_nees(false));
        let nis = s.with_nis_only(true);
        assert!(!nis.scores_nees(true));
        assert!(!nis.scores_nees(false));
    }

    #[test]
    fn a_stop_below_is_a_positive_finite_score_or_none() {
        let s = TuneSettings::default();
        assert_eq!(s.stop_below(), 0.0);
        assert_eq!(s.clone().with_stop_below(1e-5).stop_below(), 1e-5);
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert_eq!(s.clone().with_stop_below(bad).stop_below(), 0.0, "{bad}");
        }
    }
}
