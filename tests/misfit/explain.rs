//! The explanation of a misfit, tested on families of random problems, never on one file
//! (issue 38): for each kind of fault a generator (tests/common/families.rs) draws problems
//! of 1 to 3 axes with the fault's magnitude, the noise levels and the start drawn from
//! stated ranges, and each draw is tuned and explained as `autotune tune` does.
//!
//! On every draw of every kind, a cause that does not name the fault is never stated as
//! proven (the one explanation whose trial fits; where several fit, the result says the data
//! do not decide); on the kinds no hypothesis covers, no cause is named at all. `families_sample` runs a fixed sample in the suite; `families` (ignored;
//! `cargo test --release --test misfit -- --ignored --exact explain::families`) runs 30 draws per kind and
//! prints each kind's rate of a right first explanation, which docs/src/tune.md states.

use crate::families;

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
    /// The seconds and evaluations of the tune and of the trials.
    spent: String,
    what: String,
    /// The free parameters of the axes the fault does not touch that have a stated
    /// resolution, and those farther from their truth than it.
    decoupled: usize,
    decoupled_off: Vec<String>,
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
    // No wall-time limit a test machine reaches: the default 120 s guards a user's run, and
    // in a loaded test run it would end a search early and change what is judged.
    let settings = TuneSettings::default()
        .with_confirm_seeds(12)
        .and_then(|s| s.with_max_seconds(3600.0))
        .unwrap();
    let result = tune(e, &d.start, &d.fixed, &mc, &settings, &Silent).expect("the tune runs");
    let tuned_at = t0.elapsed().as_secs_f64();
    let explanations: Vec<Explanation> =
        explain(e, &result, &mc, &settings).expect("the explanation runs");
    // Where a draw's time goes: the tune with its certificate, then the trials.
    let certified: usize = result.certificate.as_ref().map_or(0, |c| {
        c.starts
            .iter()
            .skip(1)
            .map(|s| s.evaluations + s.refine_evaluations)
            .sum()
    });
    let tried: usize = explanations
        .iter()
        .filter_map(|x| x.trial.as_ref())
        .map(|t| t.evaluations)
        .sum();
    let spent = format!(
        "tune {tuned_at:.1} s, {} evaluations + {certified} certifying; trials {:.1} s, {tried} evaluations",
        result.evaluations + result.refine_evaluations,
        t0.elapsed().as_secs_f64() - tuned_at,
    );
    let res = result.resolution.as_deref();
    let mut decoupled = 0;
    let mut decoupled_off = Vec::new();
    for i in 0..d.truth.len() {
        if d.fixed[i] || d.faulted.contains(&d.param_axis(i)) {
            continue;
        }
        // A run that states no resolution (its budget ran out) has nothing to hold it to.
        let Some(f) = res.and_then(|r| r[i].factor) else {
            continue;
        };
        decoupled += 1;
        let name = &e.params().params[i].name;
        let off = (result.tuned[i] / d.truth[i]).ln().abs();
        if off > f.ln() {
            decoupled_off.push(format!(
                "{name} {:.4} (truth {:.4}, resolution ×{f:.3})",
                result.tuned[i], d.truth[i]
            ));
        }
    }
    Outcome {
        decoupled,
        decoupled_off,
        status: result.status,
        fitted: explanations
            .iter()
            .filter(|x| x.fits())
            .map(|x| cause_name(&x.cause))
            .collect(),
        seconds: t0.elapsed().as_secs_f64(),
        spent,
        what: d.what.clone(),
    }
}

/// One kind's draws: how many were right first, the draws where a wrong cause was stated
/// as proven, and the decoupled axes' parameters checked and those off their truth.
struct Row {
    kind: Kind,
    right: usize,
    wrong: Vec<String>,
    decoupled: usize,
    decoupled_off: Vec<String>,
}

/// `draws` draws of every kind from seeds 1, 2, …, a [`Row`] per kind.
fn run(draws: u64) -> Vec<Row> {
    let mut lines = Vec::new();
    let mut table = Vec::new();
    // AUTOTUNE_FAMILIES=TimeStep,Delay runs only those kinds (while developing).
    let only = std::env::var("AUTOTUNE_FAMILIES").ok();
    let kinds: Vec<Kind> = Kind::ALL
        .into_iter()
        .filter(|k| {
            only.as_ref()
                .is_none_or(|o| o.split(',').any(|x| x == format!("{k:?}")))
        })
        .collect();
    // Every kind's draws side by side (the tune and its certification are serial; the
    // trials run side by side within a draw): one kind at a time left a core idle while its
    // slowest draw finished. Reported by kind, in seed order.
    use rayon::prelude::*;
    let jobs: Vec<(Kind, u64)> = kinds
        .iter()
        .flat_map(|&k| (1..=draws).map(move |seed| (k, seed)))
        .collect();
    // In a pool of their own: in rayon's global pool, which the other tests of this binary
    // share, their searches waited behind these draws (measured: a one-second tune still
    // waiting after a minute).
    let pool = rayon::ThreadPoolBuilder::new()
        .build()
        .expect("a thread pool");
    let mut outcomes = pool
        .install(|| {
            jobs.par_iter()
                .map(|&(kind, seed)| {
                    let o = conclude(&draw(kind, seed));
                    eprintln!(
                        "  ({kind:?} seed {seed} done in {:.1} s: {})",
                        o.seconds, o.spent
                    );
                    o
                })
                .collect::<Vec<Outcome>>()
        })
        .into_iter();
    for kind in kinds {
        let mut row = Row {
            kind,
            right: 0,
            wrong: Vec::new(),
            decoupled: 0,
            decoupled_off: Vec::new(),
        };
        let mut unseen = 0;
        let outcomes: Vec<Outcome> = outcomes.by_ref().take(draws as usize).collect();
        for (o, seed) in outcomes.into_iter().zip(1..) {
            if o.right(kind) {
                row.right += 1;
            }
            if o.status == TuneStatus::Consistent {
                unseen += 1;
            }
            if let Some(c) = o.wrong_proven(kind) {
                row.wrong.push(format!("seed {seed} ({}): {c}", o.what));
            }
            eprintln!(
                "{kind:?} seed {seed}: {:?}, fitted {:?} ({:.1} s) — {}; decoupled off: {:?}",
                o.status, o.fitted, o.seconds, o.what, o.decoupled_off
            );
            row.decoupled += o.decoupled;
            row.decoupled_off
                .extend(o.decoupled_off.iter().map(|x| format!("seed {seed}: {x}")));
        }
        eprintln!("{kind:?}: {} of {draws} right first", row.right);
        lines.push(format!(
            "| {kind:?} | {draws} | {unseen} | {} of {draws} | {} | {} of {} |",
            row.right,
            row.wrong.len(),
            row.decoupled - row.decoupled_off.len(),
            row.decoupled
        ));
        table.push(row);
    }
    // The table docs/src/tune.md shows.
    eprintln!(
        "| kind | draws | tuned consistent (fault not seen) | right first | wrong cause proven | decoupled parameters within their resolution |"
    );
    eprintln!("| --- | --- | --- | --- | --- | --- |");
    for l in &lines {
        eprintln!("{l}");
    }
    table
}

/// A fixed sample of every kind (5 draws each): no wrong cause is ever stated as proven.
#[test]
fn families_sample() {
    let draws = std::env::var("AUTOTUNE_DRAWS").map_or(5, |s| s.parse().unwrap());
    let wrong: Vec<String> = run(draws)
        .iter()
        .flat_map(|r| r.wrong.iter().map(move |x| format!("{:?} {x}", r.kind)))
        .collect();
    assert!(
        wrong.is_empty(),
        "wrong causes stated as proven: {wrong:#?}"
    );
}

/// 30 draws of every kind: the first explanation names the fault on at least 90% (the
/// issue's bar), a wrong cause is never stated as proven, the kinds no hypothesis covers
/// end with none named, and the parameters of the axes the fault does not touch land
/// within their stated resolution (two standard deviations) of their truth.
#[test]
#[ignore = "about an hour: run with --ignored families"]
fn families() {
    let draws = 30;
    let table = run(draws);
    for r in &table {
        let k = r.kind;
        assert!(
            r.wrong.is_empty(),
            "{k:?}: wrong causes proven: {:#?}",
            r.wrong
        );
        assert!(
            r.right as f64 >= 0.9 * draws as f64,
            "{k:?}: {} of {draws} right first",
            r.right
        );
        assert!(
            r.decoupled_off.is_empty(),
            "{k:?}: decoupled parameters off: {:#?}",
            r.decoupled_off
        );
    }
}

/// The tune guide's examples (docs/src/misfit-examples.md): seed 1 of every kind, tuned
/// and explained as `autotune tune` does, printed as the page's Markdown.
#[test]
#[ignore = "about ten minutes: run with --ignored examples --nocapture"]
fn examples() {
    use rayon::prelude::*;
    let pages: Vec<String> = Kind::ALL
        .par_iter()
        .map(|&kind| {
            let d = draw(kind, 1);
            let e = &d.experiment;
            let mc = *e.mc();
            let settings = TuneSettings::default().with_confirm_seeds(12).unwrap();
            let r = tune(e, &d.start, &d.fixed, &mc, &settings, &Silent).expect("the tune runs");
            let x = explain(e, &r, &mc, &settings).expect("the explanation runs");
            let mut page = format!(
                "## {kind:?}{}\n\n{} ({} {}; N = {} runs × T = {} steps). The tune ends **{:?}**",
                if kind.uncovered() {
                    " (no hypothesis covers it)"
                } else {
                    ""
                },
                d.what,
                d.axes,
                if d.axes == 1 { "axis" } else { "axes" },
                mc.runs(),
                mc.steps(),
                r.status
            );
            if let Some(c) = &r.certificate {
                page += &format!(
                    " ({} of {} searches agree on the best score J = {:.4}; recheck on {} runs {})",
                    c.agreeing,
                    c.starts.len(),
                    r.objective_final.total,
                    c.recheck_runs,
                    match c.recheck_passed {
                        Some(true) => "passes",
                        Some(false) => "fails",
                        None => "not needed: a start fit",
                    }
                );
            }
            let fitted = x.iter().filter(|x| x.fits()).count();
            page += &format!(
                ". {}\n\n```text\n",
                match fitted {
                    0 if x.is_empty() => "Nothing to explain.".to_string(),
                    0 => "None of the tried changes makes it consistent: no cause is named.".into(),
                    1 => "One change makes it consistent.".into(),
                    n => format!(
                        "{n} changes make it consistent: the data do not decide between them."
                    ),
                }
            );
            for (i, x) in x.iter().enumerate() {
                let mark = if x.fits() {
                    "fits"
                } else if x.trial.is_some() {
                    "tried"
                } else {
                    "not tried"
                };
                page += &format!("{}. [{mark}] {}\n", i + 1, x.line());
            }
            page + "```\n"
        })
        .collect();
    println!("{}", pages.join("\n"));
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
            eprintln!(
                "    score {:.4}, {} evaluations, {:?}, values {:?}",
                t.score, t.evaluations, t.status, t.values
            );
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
