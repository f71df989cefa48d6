//! Issue #22, item 4: under a misfit, the best fit must not move the parameters of axes
//! that no matrix couples to the wrong one. The tuner searches each decoupled block
//! (`Structure::blocks`) on its own statistics.
//!
//! Tolerance of the seed counts: each seed's check "every y/z parameter within its stated
//! resolution of the truth" is a ~95% statement per parameter for a correct tuner
//! (resolution = two standard deviations of the estimate the gate's runs give), so a
//! correct tuner could miss it on a seed now and then; 18 of 20 allows two misses. The
//! pooled search of today's main moves them by far more than their resolution on every seed
//! (the issue measured ×1.29, ×1.37, ×0.84, ×0.83), which 18 of 20 cannot pass.

use autotune::Structure;
use std::path::PathBuf;

use autotune::internals::experiment::Experiment;
use autotune::internals::problem::Problem;
use autotune::internals::tune::{Silent, TuneResult, TuneSettings, tune};
use rayon::prelude::*;

fn misfit(name: &str) -> Problem {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/misfit")
        .join(format!("{name}.toml"));
    Problem::load(&path).expect("test problem loads")
}

fn problem_from(text: &str) -> Problem {
    Problem::from_toml(text, &PathBuf::from("inline.toml")).expect("inline problem loads")
}

fn run(p: &Problem, seed: u64) -> TuneResult {
    let start = p.params().values();
    let fixed: Vec<bool> = p.params().params.iter().map(|q| q.fixed).collect();
    let mc = p.mc().with_seed(seed);
    // No wall-time limit a test machine reaches (as in explain.rs).
    let settings = TuneSettings::default().with_max_seconds(3600.0).unwrap();
    let r = tune(p, &start, &fixed, &mc, &settings, &Silent).unwrap();
    eprintln!(
        "{} seed {seed}: {:?} separable {} {} evals {:.2} s tuned {:?} res {:?}",
        p.name(),
        r.status,
        r.separable,
        r.evaluations,
        r.seconds,
        r.tuned,
        r.resolution
            .as_ref()
            .map(|v| v.iter().map(|x| x.factor).collect::<Vec<_>>())
    );
    r
}

/// Whether every named parameter is within its stated resolution of `truth`.
fn within_resolution(p: &Problem, r: &TuneResult, names: &[&str], truth: &[f64]) -> bool {
    let Some(res) = &r.resolution else {
        return false;
    };
    names.iter().zip(truth).all(|(name, &t)| {
        let i = p.params().index(name).unwrap();
        let factor = res[i].factor.unwrap_or(1.0);
        (r.tuned[i] / t).ln().abs() <= factor.ln()
    })
}

#[test]
fn issue22_cv2d_is_two_blocks() {
    let p = autotune::internals::problem::Problem::load(
        &PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("problems/cv2d.toml"),
    )
    .unwrap();
    let blocks = p.blocks().expect("two decoupled axes");
    assert_eq!(blocks.len(), 2);
    let names = p.params().names();
    let params: Vec<Vec<&str>> = blocks
        .iter()
        .map(|b| b.params.iter().map(|&i| names[i]).collect())
        .collect();
    assert_eq!(params, [["q_accel_x", "r_pos_x"], ["q_accel_y", "r_pos_y"]]);
    assert_eq!(blocks[0].states, [0, 1]);
    assert_eq!(blocks[1].states, [2, 3]);
    assert_eq!(blocks[0].measurements, [0]);
    assert_eq!(blocks[1].measurements, [1]);
}

#[test]
fn issue22_a_mapped_truth_state_joins_its_axis_and_three_axes_are_three_blocks() {
    let p = misfit("decoupled_axes");
    let blocks = p.blocks().expect("three decoupled axes");
    assert_eq!(blocks.len(), 3);
    assert_eq!(blocks[0].states, [0, 1]);
    assert_eq!(blocks[2].measurements, [2]);
}

/// cv2d with one matrix entry replaced, which must couple the axes into one block.
fn cv2d_with(from: &str, to: &str) -> Problem {
    let text = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("problems/cv2d.toml"),
    )
    .unwrap();
    assert!(text.contains(from), "{from}");
    problem_from(&text.replacen(from, to, 1))
}

#[test]
fn issue22_an_off_diagonal_f_or_r_entry_across_axes_is_one_block() {
    // F[0][2]: x moves with y.
    let f = cv2d_with("F = [[1.0, 1.0, 0.0, 0.0],", "F = [[1.0, 1.0, 0.1, 0.0],");
    assert_eq!(f.blocks(), None, "filter and truth F coupled");
    // A truth R correlated across the two position measurements.
    let r = cv2d_with(
        "R = [\n  { kind = \"diag\", indices = [0], value = 1.0 },",
        "R = [\n  { kind = \"matrix\", matrix = [[1.0, 0.5], [0.5, 1.0]], value = 1.0 },\n  { kind = \"diag\", indices = [0], value = 1.0 },",
    );
    assert_eq!(r.blocks(), None, "truth R coupled");
}

#[test]
fn issue22_one_wrong_axis_leaves_the_decoupled_axes_within_their_resolution() {
    let p = misfit("decoupled_axes");
    let names = ["q_y", "q_z", "r_y", "r_z"];
    let truth = [0.1, 0.3, 4.0, 1.0];
    let t0 = std::time::Instant::now();
    // The seeds side by side (one after another kept a core idle for a third of the time).
    let held = (1..=20u64)
        .into_par_iter()
        .filter(|&s| {
            let r = run(&p, s);
            assert!(r.separable);
            within_resolution(&p, &r, &names, &truth)
        })
        .count();
    eprintln!("{held} of 20 seeds in {:.1} s", t0.elapsed().as_secs_f64());
    assert!(
        held >= 18,
        "{held} of 20 seeds kept y and z within resolution"
    );
}

#[test]
fn issue22_a_wrong_fixed_q_leaves_the_other_axis_within_its_resolution() {
    let p = misfit("fixed_q_two_axes");
    let names = ["q_y", "r_y"];
    let truth = [0.1, 4.0];
    let t0 = std::time::Instant::now();
    let held = (1..=20u64)
        .into_par_iter()
        .filter(|&s| {
            let r = run(&p, s);
            within_resolution(&p, &r, &names, &truth)
        })
        .count();
    eprintln!("{held} of 20 seeds in {:.1} s", t0.elapsed().as_secs_f64());
    assert!(held >= 18, "{held} of 20 seeds kept y within resolution");
}

#[test]
fn issue22_the_block_search_does_not_depend_on_the_thread_count() {
    // Exact scoring runs a block's candidates in parallel; the blocks run in order and each
    // books its evaluations in point order, so one thread and several give the same bits.
    let p = misfit("fixed_q_two_axes");
    let on = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run(&p, 3))
    };
    let (one, many) = (on(1), on(3));
    assert!(one.separable);
    assert_eq!(one.tuned, many.tuned);
    assert_eq!(one.history, many.history);
    assert_eq!(one.evaluations, many.evaluations);
}
