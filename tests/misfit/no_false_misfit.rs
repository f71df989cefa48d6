//! No false misfit (issue 38): on random linear problems whose filter has the truth's
//! structure, started ×0.1 to ×10 off and with one random parameter's upper bound below its
//! truth, `tune` never claims that no value of the free parameters fits.
//!
//! The problems are the families' generator's (tests/common/families.rs) with nothing
//! wrong: 1 to 3 axes, random step, noise levels and start. One free parameter, drawn at
//! random, gets an upper bound ×[0.1, 0.7] of its truth, so the first search stops on it and
//! the bound must be widened before anything is concluded.
//!
//! Tolerance: a consistent filter fails its confirmation with probability at most 1% (the
//! band's definition), so a tune can end undecided (the certification's recheck on 4× the
//! runs then passes) on a few problems by chance: at most 4 of 100 (binomial, p = 0.01:
//! P(X ≥ 5) = 0.3%). A claimed misfit is allowed on none.

use crate::families;

use autotune::internals::experiment::Experiment;
use autotune::internals::tune::{Silent, TuneSettings, TuneStatus, tune};
use families::{Kind, Rng, draw};

/// What one problem's tune ended in.
struct Ended {
    status: TuneStatus,
    holds: bool,
    /// For an undecided run: whether the recheck on more runs passed (the only honest
    /// reason for a right structure to end undecided).
    recheck_passed: Option<bool>,
    what: String,
}

fn tune_one(seed: u64) -> Ended {
    let mut d = draw(Kind::Nothing, seed);
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9) ^ 0xB0D5);
    let i = rng.below(d.truth.len());
    let upper = d.truth[i] * rng.uniform(0.1, 0.7);
    let p = &mut d.experiment.definition.params.params[i];
    p.upper = upper;
    p.lower = p.lower.min(upper / 10.0);
    d.start[i] = d.start[i].min(upper);
    p.value = d.start[i];
    let name = p.name.clone();
    let e = &d.experiment;
    let mc = *e.mc();
    // No wall-time limit a test machine reaches (as in explain.rs).
    let settings = TuneSettings::default().with_max_seconds(3600.0).unwrap();
    let r = tune(e, &d.start, &d.fixed, &mc, &settings, &Silent).expect("the tune runs");
    Ended {
        status: r.status,
        holds: r.confirmation.holds(),
        recheck_passed: r.certificate.as_ref().and_then(|c| c.recheck_passed),
        what: format!(
            "{} axes, {name} bounded at ×{:.2} of its truth, start {:?}, tuned {:?}, {} of {} seeds",
            d.axes,
            upper / d.truth[i],
            d.start,
            r.tuned,
            r.confirmation.passed,
            r.confirmation.seeds
        ),
    }
}

fn run(seeds: std::ops::RangeInclusive<u64>, undecided_allowed: usize) {
    let mut claimed = Vec::new();
    let mut undecided = Vec::new();
    // The problems side by side: a tune's Monte Carlo keeps both cores busy only part of
    // the time (one problem after another: 141% of two cores). Judged in seed order.
    use rayon::prelude::*;
    let seeds: Vec<u64> = seeds.collect();
    let total = seeds.len();
    let ended: Vec<Ended> = seeds.par_iter().map(|&seed| tune_one(seed)).collect();
    for (&seed, o) in seeds.iter().zip(ended) {
        eprintln!("seed {seed}: {:?} — {}", o.status, o.what);
        match o.status {
            TuneStatus::Consistent => {
                assert!(o.holds, "seed {seed}: consistent without its confirmation");
            }
            TuneStatus::Undecided => {
                assert_eq!(
                    o.recheck_passed,
                    Some(true),
                    "seed {seed}: undecided for another reason than Monte Carlo noise: {}",
                    o.what
                );
                undecided.push(format!("seed {seed}: {}", o.what));
            }
            _ => claimed.push(format!("seed {seed}: {:?}: {}", o.status, o.what)),
        }
    }
    eprintln!(
        "{} of {total} consistent, {} undecided, {} claimed a misfit",
        total - undecided.len() - claimed.len(),
        undecided.len(),
        claimed.len()
    );
    assert!(
        claimed.is_empty(),
        "a misfit (or no fit) claimed on a right structure: {claimed:#?}"
    );
    assert!(
        undecided.len() <= undecided_allowed,
        "{} undecided (at most {undecided_allowed} by chance): {undecided:#?}",
        undecided.len()
    );
}

/// 100 problems (about 30 s on two cores; measured: 100 consistent, none undecided).
#[test]
fn no_false_misfit_on_100_right_problems_with_a_bound_below_the_truth() {
    run(1..=100, 4);
}
