//! The certification of a misfit ([`crate::tune::certify`]) on mocks whose least J is known:
//! a misfit every start agrees on is proven, one that more runs dispel is undecided, and
//! the run's result books every start's evaluations and time.

use super::*;
use crate::tune::certify::{RECHECK, STARTS, needed};

/// Components 0 and 1 both follow p0 but are off by `e^{±1/2}` (see [`Mock::misfit`]),
/// component 2 follows p1: `J = [(d0 + ½)² + (d0 − ½)² + d1²] / 3`, least at the truth with
/// J = 1/6, and no value makes the filter consistent. Below `below_runs` Monte Carlo runs.
fn misfit(below_runs: usize) -> Mock {
    Mock::new(&[0.3, 20.0], &[&[1.0, 0.0], &[1.0, 0.0], &[0.0, 1.0]])
        .misfit(&[0.5, -0.5, 0.0], below_runs)
}
const MISFIT_J: f64 = 1.0 / 6.0;

/// The run without its certification (what [`certify`] starts from) and with it.
fn first_and_certified(mock: impl Fn() -> Mock) -> (TuneResult, TuneResult, Mock) {
    let s = settings(Scoring::Exact).with_local(LocalSearch::Simplex);
    let first = run(&mock(), &s.clone().with_certify(false));
    let m = mock();
    let r = run(&m, &s);
    (first, r, m)
}

#[test]
fn a_misfit_every_start_agrees_on_is_proven() {
    let (first, r, mock) = first_and_certified(|| misfit(usize::MAX));
    assert_eq!(first.status, TuneStatus::Inconsistent, "{first:#?}");
    let cert = r.certificate.as_ref().expect("certified");
    assert_eq!(r.status, TuneStatus::Inconsistent, "{cert:#?}");
    assert!(cert.proven, "{cert:#?}");
    // Every start searched (none fit), each to the least J (the simplex's J_STOP above it).
    assert_eq!(cert.starts.len(), STARTS, "{cert:#?}");
    assert_eq!(cert.agreeing, STARTS, "{cert:#?}");
    for s in &cert.starts {
        assert!((s.score - MISFIT_J).abs() < 1e-8, "{s:?}");
        assert_eq!(s.passed, 0, "{s:?}");
    }
    assert!((r.objective_final.total - MISFIT_J).abs() < 1e-8);
    assert!(log_error(&mock, &r.tuned) < 1e-3, "{:?}", r.tuned);
    // The recheck ran on RECHECK times the gate's runs, and failed.
    assert_eq!(cert.recheck_runs, RECHECK * mock.mc().runs());
    assert_eq!(cert.recheck_passed, Some(false));
    assert!(mock.runs.lock().unwrap().contains(&cert.recheck_runs));
    // The first start is the search's own result, the others distinct points.
    assert_eq!(bits(&cert.starts[0].start), bits(&first.tuned));
    for (i, a) in cert.starts.iter().enumerate() {
        for b in &cert.starts[..i] {
            assert_ne!(bits(&a.start), bits(&b.start));
        }
    }
    books_every_start(&first, &r);
    // The run's own start and its J there stay the run's.
    assert_eq!(bits(&r.initial), bits(&first.initial));
    assert_eq!(r.objective_initial.total, first.objective_initial.total);
}

/// The certified result books the first search's evaluations and every start's, the
/// searches' and the refinements' apart, and their time.
fn books_every_start(first: &TuneResult, r: &TuneResult) {
    let cert = r.certificate.as_ref().expect("certified");
    let spent: usize = cert.starts.iter().map(|s| s.evaluations).sum();
    assert_eq!(r.evaluations, first.evaluations + spent);
    let refined: usize = cert.starts.iter().map(|s| s.refine_evaluations).sum();
    assert_eq!(r.refine_evaluations, first.refine_evaluations + refined);
    let seconds: f64 = cert.starts.iter().map(|s| s.seconds).sum();
    assert!(r.seconds > seconds, "{} ≤ {seconds}", r.seconds);
}

/// Under Monte Carlo scoring each start's search is refined on more runs after it
/// converged: the certificate books those evaluations too (each start's count checked
/// against a search run from that start on its own).
#[test]
fn a_monte_carlo_misfit_books_each_starts_search_and_refinement() {
    let mock = || misfit(usize::MAX).without_exact_sums();
    let s = settings(Scoring::MonteCarlo).with_local(LocalSearch::Simplex);
    let first = run(&mock(), &s.clone().with_certify(false));
    let r = run(&mock(), &s);
    let cert = r.certificate.as_ref().expect("certified");
    assert_eq!(r.status, TuneStatus::Inconsistent, "{cert:#?}");
    assert!(
        cert.starts.iter().all(|c| c.refine_evaluations > 0),
        "{cert:#?}"
    );
    books_every_start(&first, &r);
    // A start's search on its own: the widened box, the certification's seeds.
    let m = mock();
    let wide = crate::experiment::Rebounded::new(&m, &cert.bounds);
    let quiet = s
        .clone()
        .with_certify(false)
        .with_confirm_seed(Some(first.confirm_seed));
    let fixed = vec![false; first.tuned.len()];
    let alone = tune(
        &wide,
        &cert.starts[1].start,
        &fixed,
        m.mc(),
        &quiet,
        &Silent,
    )
    .unwrap();
    assert_eq!(alone.evaluations, cert.starts[1].evaluations);
    assert_eq!(alone.refine_evaluations, cert.starts[1].refine_evaluations);
}

#[test]
fn a_misfit_that_more_runs_do_not_repeat_is_undecided() {
    // The misfit shows at the gate's runs but not on the recheck's RECHECK times as many.
    let below = RECHECK * misfit(0).mc().runs();
    let (first, r, _) = first_and_certified(|| misfit(below));
    assert_eq!(first.status, TuneStatus::Inconsistent, "{first:#?}");
    let cert = r.certificate.as_ref().expect("certified");
    assert_eq!(r.status, TuneStatus::Undecided, "{cert:#?}");
    assert!(!cert.proven);
    assert_eq!(cert.recheck_passed, Some(true), "{cert:#?}");
    assert_eq!(cert.agreeing, STARTS);
}

/// A result of the quadratic mock with its status and widening set.
fn with(status: TuneStatus, widened_at_bound: Option<bool>) -> TuneResult {
    let mock = quadratic();
    let mut r = run(&mock, &settings(Scoring::Exact).with_certify(false));
    r.status = status;
    r.widened.clear();
    r.at_bound = vec![false; r.tuned.len()];
    if let Some(at) = widened_at_bound {
        r.widened.push(Widening {
            param: 1,
            from: (1e-4, 1e4),
            to: (1e-6, 1e6),
        });
        r.at_bound[1] = at;
    }
    r
}

#[test]
fn a_certificate_is_needed_for_a_failed_confirmation_or_a_bound_that_stopped_the_search() {
    use TuneStatus::*;
    let cases = [
        (Inconsistent, None, true),
        (Consistent, None, false),
        (Consistent, Some(true), false),
        (BudgetExhausted, Some(true), true),
        (BudgetExhausted, Some(false), false),
        (BudgetExhausted, None, false),
        (Undecided, Some(true), false),
    ];
    for (status, widened, want) in cases {
        assert_eq!(
            needed(&with(status, widened)),
            want,
            "{status:?}, widened at bound {widened:?}"
        );
    }
}

/// A search told to stop below a score stops soon after an evaluation below it (an
/// explanation's trial asks only whether some value fits): a batch of the global stage
/// already under way is finished (41 evaluations on the simplex's run), but no local search
/// starts after it. Without the stop the searches run on to J_STOP. (Gauss–Newton solves
/// the quadratic in 6 evaluations: nothing to cut short.)
#[test]
fn a_search_stops_once_its_score_is_below_stop_below() {
    let s = settings(Scoring::Exact)
        .with_local(LocalSearch::Simplex)
        .with_certify(false);
    let full = run(&quadratic(), &s);
    let stopped = run(&quadratic(), &s.clone().with_stop_below(1.0));
    let j = stopped.objective_final.total;
    assert!(j < 1.0 && j > J_STOP, "J {j:.3e}");
    assert!(
        2 * stopped.evaluations < full.evaluations,
        "{} evaluations, {} without the stop",
        stopped.evaluations,
        full.evaluations
    );
}
