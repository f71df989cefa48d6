//! The explanation of a misfit, tested on families of random problems, never on one file
//! (issue 38): for each kind of fault a generator (tests/common/families.rs) draws problems
//! of 1 to 3 axes with the fault's magnitude, the noise levels and the start drawn from
//! stated ranges, and each draw is tuned and explained as `autotune tune` does.
//!
//! On every draw of every kind, a cause that does not name the fault is never stated as
//! proven (the one explanation whose trial fits; where several fit, the result says the data
//! do not decide); on the kinds no hypothesis covers, no cause is named at all. `families_sample` runs a fixed sample in the suite; `families` (ignored;
//! `cargo test --release --test explain -- --ignored families`) runs 30 draws per kind and
//! prints each kind's rate of a right first explanation, which docs/src/tune.md states.

#[path = "common/families.rs"]
mod families;

use std::time::Instant;

use autotune::internals::experiment::Experiment;
use autotune::internals::explain::{Explanation, explain};
use autotune::internals::tune::{Silent, TuneSettings, TuneStatus, tune};
use families::{Draw, Kind, cause_name, draw};

/// What autotune concluded on one draw.
struct Outcome {
    status: TuneStatus,
    /// The causes of the explanations whose trial fit, in rank order.
    fitted: Vec<String>,
    seconds: f64,
    what: String,
}

impl Outcome {
    /// The first explanation names the fault (for an uncovered kind: nothing is named).
    fn right(&self, kind: Kind) -> bool {
        match self.fitted.first() {
            Some(c) => kind.right(c),
            None => kind.uncovered() && self.status != TuneStatus::Consistent,
        }
    }

    /// A cause that does not name the fault is stated as proven: it is the one change that
    /// fits. (Where several fit, the result says that the data do not decide between them
    /// and states none as proven; a wrong one first among them counts against the rate of
    /// a right first explanation instead.)
    fn wrong_proven(&self, kind: Kind) -> Option<&str> {
        match self.fitted.as_slice() {
            // An uncovered kind must end with none named.
            [first, ..] if kind.uncovered() => Some(first),
            [only] if !kind.right(only) => Some(only),
            _ => None,
        }
    }
}

fn conclude(d: &Draw) -> Outcome {
    let t0 = Instant::now();
    let e = &d.experiment;
    let mc = *e.mc();
    let settings = TuneSettings::default().with_confirm_seeds(12).unwrap();
    let result = tune(e, &d.start, &d.fixed, &mc, &settings, &Silent).expect("the tune runs");
    let explanations: Vec<Explanation> =
        explain(e, &result, &mc, &settings).expect("the explanation runs");
    Outcome {
        status: result.status,
        fitted: explanations
            .iter()
            .filter(|x| x.fits())
            .map(|x| cause_name(&x.cause))
            .collect(),
        seconds: t0.elapsed().as_secs_f64(),
        what: d.what.clone(),
    }
}

/// `draws` draws of every kind from seeds 1, 2, …: per kind, the rate of a right first
/// explanation and every draw where a wrong cause was stated as proven.
fn run(draws: u64) -> Vec<(Kind, usize, Vec<String>)> {
    let mut lines = Vec::new();
    let mut table = Vec::new();
    // AUTOTUNE_FAMILIES=TimeStep,Delay runs only those kinds (while developing).
    let only = std::env::var("AUTOTUNE_FAMILIES").ok();
    let kinds = Kind::ALL.into_iter().filter(|k| {
        only.as_ref()
            .is_none_or(|o| o.split(',').any(|x| x == format!("{k:?}")))
    });
    for kind in kinds {
        let (mut right, mut wrong, mut unseen) = (0, Vec::new(), 0);
        // The draws side by side (the tune and its certification are serial; the trials
        // run side by side within a draw), reported in seed order.
        use rayon::prelude::*;
        let outcomes: Vec<Outcome> = (1..=draws)
            .into_par_iter()
            .map(|seed| conclude(&draw(kind, seed)))
            .collect();
        for (o, seed) in outcomes.into_iter().zip(1..) {
            if o.right(kind) {
                right += 1;
            }
            if o.status == TuneStatus::Consistent {
                unseen += 1;
            }
            if let Some(c) = o.wrong_proven(kind) {
                wrong.push(format!("seed {seed} ({}): {c}", o.what));
            }
            eprintln!(
                "{kind:?} seed {seed}: {:?}, fitted {:?} ({:.1} s) — {}",
                o.status, o.fitted, o.seconds, o.what
            );
        }
        eprintln!("{kind:?}: {right} of {draws} right first");
        lines.push(format!(
            "| {kind:?} | {draws} | {unseen} | {right} of {draws} | {} |",
            wrong.len()
        ));
        table.push((kind, right, wrong));
    }
    // The table docs/src/tune.md shows.
    eprintln!(
        "| kind | draws | tuned consistent (fault not seen) | right first | wrong cause proven |"
    );
    eprintln!("| --- | --- | --- | --- | --- |");
    for l in &lines {
        eprintln!("{l}");
    }
    table
}

/// A fixed sample of every kind (5 draws each): no wrong cause is ever stated as proven.
#[test]
fn families_sample() {
    let draws = std::env::var("AUTOTUNE_DRAWS").map_or(5, |s| s.parse().unwrap());
    let table = run(draws);
    let wrong: Vec<String> = table
        .iter()
        .flat_map(|(k, _, w)| w.iter().map(move |x| format!("{k:?} {x}")))
        .collect();
    assert!(
        wrong.is_empty(),
        "wrong causes stated as proven: {wrong:#?}"
    );
}

/// 30 draws of every kind: the first explanation names the fault on at least 90% (the
/// issue's bar), a wrong cause is never stated as proven, and the kinds no hypothesis covers
/// end with none named.
#[test]
#[ignore = "about an hour: run with --ignored families"]
fn families() {
    let draws = 30;
    let table = run(draws);
    for (k, right, wrong) in &table {
        assert!(wrong.is_empty(), "{k:?}: wrong causes proven: {wrong:#?}");
        assert!(
            *right as f64 >= 0.9 * draws as f64,
            "{k:?}: {right} of {draws} right first"
        );
    }
}

/// One draw, every explanation printed (AUTOTUNE_FAMILIES=Kind, AUTOTUNE_SEED=n).
#[test]
#[ignore = "a probe for development"]
fn probe() {
    let kind = std::env::var("AUTOTUNE_FAMILIES").unwrap_or_else(|_| "TimeStep".into());
    let seed: u64 = std::env::var("AUTOTUNE_SEED").map_or(1, |s| s.parse().unwrap());
    let kind = *Kind::ALL.iter().find(|k| format!("{k:?}") == kind).unwrap();
    let d = draw(kind, seed);
    let e = &d.experiment;
    let mc = *e.mc();
    let settings = TuneSettings::default().with_confirm_seeds(12).unwrap();
    let t0 = Instant::now();
    let result = tune(e, &d.start, &d.fixed, &mc, &settings, &Silent).unwrap();
    eprintln!("{} — truth {:?} start {:?}", d.what, d.truth, d.start);
    eprintln!(
        "tune {:?} in {:.1} s: tuned {:?}, J {:.4}, {} of {} seeds, certificate {:#?}",
        result.status,
        t0.elapsed().as_secs_f64(),
        result.tuned,
        result.objective_final.total,
        result.confirmation.passed,
        result.confirmation.seeds,
        result.certificate.as_ref().map(|c| (
            c.agreeing,
            c.recheck_passed,
            c.starts
                .iter()
                .map(|s| (s.score, s.passed, s.status))
                .collect::<Vec<_>>()
        ))
    );
    let t1 = Instant::now();
    for x in explain(e, &result, &mc, &settings).unwrap() {
        eprintln!("- {}", x.line());
        if let Some(t) = &x.trial {
            eprintln!("    score {:.4}, {} evaluations", t.score, t.evaluations);
        }
    }
    eprintln!("explain {:.1} s", t1.elapsed().as_secs_f64());
}

#[test]
#[ignore = "a probe for development"]
fn probe_gain() {
    use autotune::internals::experiment::{Hypothesis, Hypothesized};
    let d = draw(Kind::Misalignment, 1);
    eprintln!("{}", d.what);
    let e = Hypothesized::new(&d.experiment, Hypothesis::MeasurementMatrix, &d.truth).unwrap();
    let mc = *e.mc();
    let k = e.added().len();
    let settings = TuneSettings::default()
        .with_confirm_seeds(12)
        .unwrap()
        .with_certify(false);
    for local in [
        autotune::internals::tune::LocalSearch::GaussNewton,
        autotune::internals::tune::LocalSearch::Simplex,
    ] {
        let mut start = d.truth.clone();
        start.extend(vec![1.0; k]);
        let fixed = vec![false; start.len()];
        let t0 = Instant::now();
        let t = tune(
            &e,
            &start,
            &fixed,
            &mc,
            &settings.clone().with_local(local),
            &Silent,
        )
        .unwrap();
        eprintln!(
            "{local:?}: {:?} J {:.4} evals {} in {:.1} s tuned {:?}",
            t.status,
            t.objective_final.total,
            t.evaluations,
            t0.elapsed().as_secs_f64(),
            t.tuned
        );
    }
}
