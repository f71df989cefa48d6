//! What the explanation of a misfit writes and says where it cannot try a change (issue 22,
//! reworked for issue 38); the causes themselves are tested on families of random problems
//! in tests/misfit/explain.rs.

use std::path::{Path, PathBuf};

use autotune::internals::experiment::Experiment;
use autotune::internals::explain::explain;
use autotune::internals::problem::Problem;
use autotune::internals::tune::{Silent, TuneStatus, tune};

fn misfit(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/misfit")
        .join(name)
}

#[test]
fn a_misfit_writes_a_rejected_config_that_starts_with_its_explanations() {
    use assert_cmd::cargo::CommandCargoExt;
    let dir = tempfile::tempdir().unwrap();
    let out = std::process::Command::cargo_bin("autotune")
        .unwrap()
        .current_dir(dir.path())
        .arg("tune")
        .arg(misfit("fixed_r.toml"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{stdout}");
    assert!(!dir.path().join("tuned/fixed_r.toml").exists());
    let text = std::fs::read_to_string(dir.path().join("tuned/fixed_r.rejected.toml")).unwrap();
    assert!(text.starts_with("# REJECTED"), "{text}");
    // The fitted cause, with its trial's result, comes before any value.
    let first = text
        .find("1. a fixed parameter that is wrong (r_pos)")
        .expect(&text);
    assert!(first < text.find("[params]").unwrap(), "{text}");
    assert!(
        text.contains("no value of the free parameters makes this filter consistent (proven"),
        "{text}"
    );
    assert!(
        stdout.contains("1. a fixed parameter that is wrong (r_pos)"),
        "{stdout}"
    );
    // Still a config `check --config` reads, to reproduce the finding.
    let check = std::process::Command::cargo_bin("autotune")
        .unwrap()
        .current_dir(dir.path())
        .arg("check")
        .arg(misfit("fixed_r.toml"))
        .arg("--config")
        .arg("tuned/fixed_r.rejected.toml")
        .output()
        .unwrap();
    assert_eq!(check.status.code(), Some(1), "{check:?}");
}

/// A problem seen through the seam without its matrices: what a catalog model, a Rust model
/// or a worker looks like to the explanations.
struct Opaque<'a>(&'a Problem);

impl Experiment for Opaque<'_> {
    fn definition(&self) -> &autotune::internals::experiment::Definition {
        self.0.definition()
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &autotune::internals::montecarlo::McConfig,
        options: autotune::internals::experiment::RunOptions<'_>,
    ) -> Result<
        autotune::internals::stats::Accumulator,
        autotune::internals::experiment::ExperimentError,
    > {
        self.0.monte_carlo_with(theta, mc, options)
    }
}

impl autotune::Structure for Opaque<'_> {
    fn target(&self, i: usize) -> Option<autotune::internals::params::Target> {
        self.0.target(i)
    }
}

impl autotune::HeldAsCode for Opaque<'_> {}

impl autotune::Sampling for Opaque<'_> {}

/// Where the filter's model cannot be changed, no cause is named: every hypothesis is
/// listed as not tried, last, and the finding says no tried change fit.
#[test]
fn where_the_filter_cannot_be_changed_no_cause_is_named() {
    let p = Problem::load(&misfit("half_dt.toml")).unwrap();
    let e = Opaque(&p);
    let mc = *p.mc();
    let start = p.params().values();
    // No wall-time limit a test machine reaches: the Monte Carlo search runs for a minute on
    // a loaded machine, and the default 120 s would end it as out of budget.
    let settings = p.tune.clone().with_max_seconds(3600.0).unwrap();
    let r = tune(&e, &start, &[false, false], &mc, &settings, &Silent).unwrap();
    assert_eq!(r.status, TuneStatus::Inconsistent);
    let ex = explain(&e, &r, &mc, &settings).unwrap();
    assert!(ex.iter().all(|x| x.trial.is_none()), "{ex:#?}");
    assert!(ex.iter().all(|x| !x.fits()));
    assert!(
        ex.iter().all(|x| x
            .untried
            .as_deref()
            .unwrap()
            .contains("as code, not as matrices")),
        "{ex:#?}"
    );
    let lines = autotune::report::advice::family_finding(&r, &ex)
        .unwrap()
        .join("\n");
    assert!(lines.contains("not tried ("), "{lines}");
    assert!(!lines.contains("why:"), "{lines}");
}
