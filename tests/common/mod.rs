//! Helpers shared by the integration tests.
#![allow(dead_code)]

use assert_cmd::cargo::CommandCargoExt;
use std::path::PathBuf;

use autotune::internals::experiment::Experiment;
use autotune::internals::problem::Problem;

/// Path of a shipped problem file.
pub fn problem_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("problems")
        .join(format!("{name}.toml"))
}

/// Load a shipped problem.
pub fn load(name: &str) -> Problem {
    Problem::load(&problem_path(name)).expect("shipped problem must load")
}

/// The truth's noise values for each shipped problem's parameters: as written in the linear
/// problem files' [truth] sections, and as the catalog models report them.
pub fn truth_values(problem: &dyn Experiment) -> Vec<f64> {
    if let Some(v) = problem.truth_values() {
        return v;
    }
    let table: &[(&str, f64)] = match problem.info().name.as_str() {
        "cv1d" => &[("q_accel", 0.5), ("r_pos", 1.0)],
        "cv2d" => &[
            ("q_accel_x", 0.5),
            ("q_accel_y", 0.1),
            ("r_pos_x", 1.0),
            ("r_pos_y", 4.0),
        ],
        "dcmotor" => &[("q_torque", 1e-6), ("q_voltage", 1e-2), ("r_angle", 4e-6)],
        other => panic!("no truth table for {other}"),
    };
    problem
        .params()
        .params
        .iter()
        .map(|p| {
            table
                .iter()
                .find(|(n, _)| *n == p.name)
                .unwrap_or_else(|| panic!("no truth value for {}", p.name))
                .1
        })
        .collect()
}

/// `theta` with every parameter whose name starts with `prefix` multiplied by `factor`.
pub fn scaled(problem: &dyn Experiment, theta: &[f64], prefix: &str, factor: f64) -> Vec<f64> {
    problem
        .params()
        .params
        .iter()
        .zip(theta)
        .map(|(p, &v)| {
            if p.name.starts_with(prefix) {
                v * factor
            } else {
                v
            }
        })
        .collect()
}

/// Run the `autotune` binary with `args`: its exit code, stdout and stderr.
pub fn autotune(args: &[&str]) -> (Option<i32>, String, String) {
    let out = std::process::Command::cargo_bin("autotune")
        .unwrap()
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `cmd` with SIGINT, SIGTERM and SIGHUP at their default disposition in the child, for the
/// tests that interrupt it: a shell starts a background job with SIGINT ignored, autotune
/// leaves an ignored signal ignored (the user asked for it to be survived), and the test
/// would then wait out the command instead of testing its interrupt.
pub fn with_default_signals(cmd: &mut std::process::Command) -> &mut std::process::Command {
    use std::os::unix::process::CommandExt;
    // SAFETY: between fork and exec the closure calls only signal(2), which is
    // async-signal-safe, and allocates nothing.
    unsafe {
        cmd.pre_exec(|| {
            for s in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
                libc::signal(s, libc::SIG_DFL);
            }
            Ok(())
        })
    }
}

/// A filter with its error map hidden: what a filter that does not track it (a records
/// file, a worker) gives the engine, its numbers otherwise the wrapped filter's.
pub struct NoMap<F>(pub F);

impl<F: autotune::internals::filter::Filter> autotune::internals::filter::Filter for NoMap<F> {
    fn n_x(&self) -> usize {
        self.0.n_x()
    }

    fn sensor_dims(&self) -> Vec<usize> {
        self.0.sensor_dims()
    }

    fn initial(&self) -> autotune::internals::filter::Estimate {
        self.0.initial()
    }

    fn predict(
        &self,
        k: usize,
        est: &mut autotune::internals::filter::Estimate,
    ) -> autotune::internals::filter::PredictResult {
        self.0.predict(k, est)?;
        est.error_map = None;
        Ok(())
    }

    fn update(
        &self,
        k: usize,
        est: &mut autotune::internals::filter::Estimate,
        meas: &autotune::internals::measurement::Measurement,
    ) -> autotune::internals::filter::UpdateResult {
        let inn = self.0.update(k, est, meas)?;
        est.error_map = None;
        Ok(inn)
    }

    fn state_error(
        &self,
        truth: &nalgebra::DVector<f64>,
        estimate: &nalgebra::DVector<f64>,
    ) -> nalgebra::DVector<f64> {
        self.0.state_error(truth, estimate)
    }
}
