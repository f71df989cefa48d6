//! Every shipped tuned config holds on fresh seeds (issue 11, item 2): it passes the
//! default gate at the problem's N about as often as the truth's own noise does.

use crate::common;

use autotune::internals::check::check;
use autotune::internals::experiment::Experiment;
use autotune::report::tuned::TunedConfig;
use common::{load, problem_path};
use rayon::prelude::*;

/// Passes of `autotune check PROBLEM --config tuned/NAME.toml --seed S` for S = 3001…3100
/// (the seeds), through the library.
fn passes(name: &str) -> usize {
    let p = load(name);
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let theta = TunedConfig::load_values(&root.join(format!("tuned/{name}.toml")), &p).unwrap();
    assert!(problem_path(name).exists());
    // Seeds side by side: a catalog problem's N runs are one or two chunks, one core each.
    (3001..=3100)
        .into_par_iter()
        .filter(|&s| {
            check(&p, &theta, &p.mc().with_seed(s), autotune::Truth::Known)
                .unwrap()
                .verdict
                .passes()
        })
        .count()
}

/// The truth's own noise passes about 95 of 100 (at most α = 0.05 fail, fewer since the
/// Šidák correction is conservative for dependent tests); a consistent config's count is
/// Bin(100, ≥ 0.95), whose 1% quantile is 89 (the issue asks for 90). A config tuned to within the search's noise
/// of the truth loses a little more. Before issue 11 tuned/orbit2d.toml passed 72 of these
/// 100 under the textbook gate.
fn assert_holds(name: &str) {
    let n = passes(name);
    eprintln!("tuned/{name}.toml passes {n} of 100 fresh seeds");
    assert!(
        n >= 90,
        "tuned/{name}.toml passes only {n} of 100 fresh seeds"
    );
}

#[test]
fn tuned_linear_configs_hold_on_fresh_seeds() {
    for name in ["cv1d", "cv2d", "dcmotor"] {
        assert_holds(name);
    }
}

#[test]
fn tuned_ctrv_holds_on_fresh_seeds() {
    assert_holds("ctrv");
}

#[test]
fn tuned_orbit2d_holds_on_fresh_seeds() {
    assert_holds("orbit2d");
}

#[test]
fn tuned_ins_gnss_holds_on_fresh_seeds() {
    assert_holds("ins_gnss");
}
