//! The explanation of a misfit on filters held as code (a Rust model's, as a catalog
//! model's): autotune cannot change their model, but it feeds them their readings, so it
//! tries the sensor-side changes (a constant offset, a gain) on what the filter reads, and
//! lists the model's changes as not tried (issue 38).
//!
//! Families, not files: each draw is a random problem of tests/common/families.rs (1 to 3
//! axes, the step, the noise levels and the start drawn), run as a Rust model on the
//! generic engine, with one axis's sensor reading off by an offset ([1, 4] √r either way)
//! or a gain (×[1.15, 1.6] or ÷ that), or the filter's F and Q built for another step (a
//! fault of the model, which no change of the readings covers). On every draw a wrong cause
//! is never stated as proven, and the model fault ends with no cause named.
//! `code_families_sample` runs a fixed sample in the suite (one draw of each fault);
//! `code_families` (ignored) runs 30 draws of each and prints the rates docs/src/tune.md
//! states.

use crate::families;
use autotune::Structure;

use std::time::Instant;

use autotune::internals::experiment::Experiment;
use autotune::internals::explain::explain;
use autotune::internals::model::{LinearGaussianModel, TruthModel};
use autotune::internals::tune::{Silent, TuneSettings, TuneStatus, tune};
use autotune::{Measurement, RustModel, SimRng};
use families::{Kind, Rng, cause_name, draw};
use nalgebra::DVector;

/// A linear truth whose sensor reads `gain · z + offset` per component.
struct Reads {
    inner: LinearGaussianModel,
    offset: Vec<f64>,
    gain: Vec<f64>,
}

impl TruthModel for Reads {
    fn n_x(&self) -> usize {
        self.inner.n_x()
    }

    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        self.inner.initial_state(rng)
    }

    fn propagate(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        self.inner.propagate(k, x, rng)
    }

    fn measure(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        let from = out.len();
        self.inner.measure(k, x, rng, out);
        for m in &mut out[from..] {
            assert_eq!(m.sensor, 0, "the families' problems have one sensor");
            for (j, z) in m.z.iter_mut().enumerate() {
                *z = self.gain[j] * *z + self.offset[j];
            }
        }
    }
}

/// The faults drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Fault {
    /// One axis's sensor reads an offset.
    Offset,
    /// One axis's sensor reads a gain.
    Gain,
    /// The filter's F and Q built for another step: in the model, not in what it reads.
    Step,
}

impl Fault {
    const ALL: [Fault; 3] = [Fault::Offset, Fault::Gain, Fault::Step];

    /// The cause a right first explanation names (none for a fault of the model).
    fn cause(self) -> Option<&'static str> {
        match self {
            Fault::Offset => Some("sensor_bias"),
            Fault::Gain => Some("sensor_gain"),
            Fault::Step => None,
        }
    }
}

/// What one draw concluded: the causes whose trial fit, in rank order, and the status.
struct Outcome {
    status: TuneStatus,
    fitted: Vec<String>,
    what: String,
    seconds: f64,
}

fn conclude(fault: Fault, seed: u64) -> Outcome {
    let kind = if fault == Fault::Step {
        Kind::TimeStep
    } else {
        Kind::Nothing
    };
    let d = draw(kind, seed);
    let mut rng = Rng(seed ^ 0x5EED_C0DE ^ fault as u64);
    let m = d.experiment.measurement_names().len();
    let (mut offset, mut gain) = (vec![0.0; m], vec![1.0; m]);
    let a = rng.below(d.axes);
    let what = match fault {
        Fault::Offset => {
            let r = d.truth[d.axes + a];
            offset[a] =
                rng.uniform(1.0, 4.0) * r.sqrt() * if rng.unit() < 0.5 { 1.0 } else { -1.0 };
            format!(
                "sensor {a} reads {:+.3} off (√r {:.3})",
                offset[a],
                r.sqrt()
            )
        }
        Fault::Gain => {
            gain[a] = rng.either_side(1.15, 1.6);
            format!("sensor {a} reads × {:.3}", gain[a])
        }
        Fault::Step => d.what.clone(),
    };
    let truth = Reads {
        inner: d.experiment.truth.clone(),
        offset,
        gain,
    };
    let lin = d.experiment.clone();
    let mut b = RustModel::builder("as_code", truth, move |theta: &[f64]| lin.filter_at(theta))
        .states(d.experiment.state_names().to_vec())
        .measurements(d.experiment.measurement_names().to_vec());
    for (i, p) in d.experiment.params().params.iter().enumerate() {
        b = b.param(
            p.clone(),
            d.experiment.target(i).expect("a target per parameter"),
        );
    }
    let model = b
        .montecarlo(*d.experiment.mc())
        .build()
        .expect("a valid model");
    let t0 = Instant::now();
    let mc = *model.mc();
    // No wall-time limit a test machine reaches (as in explain.rs).
    let settings = TuneSettings::default()
        .with_confirm_seeds(12)
        .and_then(|s| s.with_max_seconds(3600.0))
        .unwrap();
    let result = tune(&model, &d.start, &d.fixed, &mc, &settings, &Silent).expect("tuned");
    let explanations = explain(&model, &result, &mc, &settings).expect("explained");
    // The model's changes are never tried on a filter held as code, and say why.
    for x in &explanations {
        let name = cause_name(&x.cause);
        if ![
            "sensor_bias",
            "sensor_gain",
            "fixed_parameter",
            "search_bounds",
        ]
        .contains(&name.as_str())
        {
            let why = x
                .untried
                .as_deref()
                .unwrap_or_else(|| panic!("{name} tried: {x:#?}"));
            assert!(why.contains("what the filter reads"), "{why}");
        }
    }
    Outcome {
        status: result.status,
        fitted: explanations
            .iter()
            .filter(|x| x.fits())
            .map(|x| cause_name(&x.cause))
            .collect(),
        what,
        seconds: t0.elapsed().as_secs_f64(),
    }
}

/// For each fault, its count of draws from seeds 1, 2, …: how many named it first, and the
/// draws that stated a wrong cause as proven (or any cause, for a fault of the model).
fn run(faults: &[(Fault, u64)]) -> Vec<(Fault, usize, Vec<String>)> {
    faults
        .iter()
        .map(|&(fault, draws)| {
            let mut right = 0;
            let mut wrong = Vec::new();
            for seed in 1..=draws {
                let o = conclude(fault, seed);
                eprintln!(
                    "{fault:?} seed {seed}: {:?}, fitted {:?} ({:.1} s) — {}",
                    o.status, o.fitted, o.seconds, o.what
                );
                let first_right = match (o.fitted.first(), fault.cause()) {
                    (Some(c), Some(want)) => c == want,
                    (None, None) => o.status != TuneStatus::Consistent,
                    _ => false,
                };
                right += usize::from(first_right);
                let proven_wrong = match (o.fitted.as_slice(), fault.cause()) {
                    ([first, ..], None) => Some(first.clone()),
                    ([only], Some(want)) if only != want => Some(only.clone()),
                    _ => None,
                };
                if let Some(c) = proven_wrong {
                    wrong.push(format!("seed {seed}: {c} ({})", o.what));
                }
            }
            eprintln!("{fault:?}: {right} of {draws} right first");
            (fault, right, wrong)
        })
        .collect()
}

/// A static scalar state seen by a sensor that reads it `offset` high.
struct OffsetTruth(LinearGaussianModel, f64);

impl TruthModel for OffsetTruth {
    fn n_x(&self) -> usize {
        1
    }

    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        self.0.initial_state(rng)
    }

    fn propagate(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        self.0.propagate(k, x, rng)
    }

    fn measure(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        self.0.measure(k, x, rng, out);
        for m in out.iter_mut() {
            m.z[0] += self.1;
        }
    }
}

#[test]
fn a_filter_held_as_code_is_tried_on_what_it_reads_and_its_model_is_not() {
    use autotune::internals::experiment::Hypothesis;
    use autotune::internals::explain::Cause;
    use autotune::internals::tune::LocalSearch;
    use nalgebra::{DMatrix, DVector};
    // x constant (P0 = 4), read with noise r = 1 and 3 high: no r makes the filter
    // consistent, a constant offset of the reading does.
    let one = || DMatrix::identity(1, 1);
    let truth = LinearGaussianModel::new(
        one(),
        one(),
        DMatrix::zeros(1, 1),
        one(),
        DVector::zeros(1),
        one() * 4.0,
    )
    .unwrap();
    let filter = |theta: &[f64]| autotune::internals::filter::KalmanFilter {
        F: DMatrix::identity(1, 1),
        H: DMatrix::identity(1, 1),
        Q: DMatrix::zeros(1, 1),
        R: DMatrix::identity(1, 1) * theta[0],
        x0: DVector::zeros(1),
        P0: DMatrix::identity(1, 1) * 4.0,
    };
    let model = RustModel::builder("offset", OffsetTruth(truth, 3.0), filter)
        .states(["x"])
        .measurements(["z"])
        .param(
            autotune::ParamDef::new("r", 1.0),
            autotune::Target::measurement(&[0]),
        )
        .montecarlo(autotune::McConfig::new(30, 15).unwrap().with_seed(5))
        .build()
        .unwrap();
    // Small budgets: one parameter, and a trial of one more.
    let s = TuneSettings::default()
        .with_max_evals(150)
        .and_then(|s| s.with_global_points(3))
        .and_then(|s| s.with_starts(2))
        .and_then(|s| s.with_confirm_seeds(10))
        .unwrap()
        .with_local(LocalSearch::Simplex);
    let r = tune(&model, &[1.0], &[false], model.mc(), &s, &Silent).unwrap();
    assert_eq!(r.status, TuneStatus::Inconsistent, "{:?}", r.certificate);
    let e = explain(&model, &r, model.mc(), &s).unwrap();
    let first = &e[0];
    assert_eq!(first.cause, Cause::Model(Hypothesis::SensorBias), "{e:#?}");
    assert!(first.fits(), "{first:#?}");
    assert!(
        first.evidence.contains("offset_z = 3.0"),
        "{}",
        first.evidence
    );
    let gain = e
        .iter()
        .find(|x| x.cause == Cause::Model(Hypothesis::SensorGain))
        .unwrap();
    assert!(gain.trial.is_some() && !gain.fits(), "{gain:#?}");
    for x in &e {
        if !matches!(
            x.cause,
            Cause::Model(Hypothesis::SensorBias | Hypothesis::SensorGain)
        ) {
            let why = x.untried.as_deref().unwrap_or_else(|| panic!("{x:#?}"));
            assert!(why.contains("it can change what the filter reads"), "{why}");
        }
    }
}

#[test]
fn code_families_sample() {
    for (fault, _, wrong) in run(&Fault::ALL.map(|f| (f, 1))) {
        assert!(
            wrong.is_empty(),
            "{fault:?}: a wrong cause stated as proven: {wrong:?}"
        );
    }
}

#[test]
#[ignore = "about two hours: run with --ignored code_families"]
fn code_families() {
    // AUTOTUNE_DRAWS=10 for a shorter look (the 90% bar is then 9 of 10).
    let draws = std::env::var("AUTOTUNE_DRAWS").map_or(30, |s| s.parse().unwrap());
    // AUTOTUNE_FAULTS=Step runs only those faults (while developing).
    let only = std::env::var("AUTOTUNE_FAULTS").ok();
    let faults: Vec<(Fault, u64)> = Fault::ALL
        .iter()
        .filter(|f| {
            only.as_deref()
                .is_none_or(|o| o.split(',').any(|n| n == format!("{f:?}")))
        })
        .map(|&f| (f, draws))
        .collect();
    let rows = run(&faults);
    println!("| fault | draws | right first | wrong cause proven |");
    println!("| --- | --- | --- | --- |");
    for (fault, right, wrong) in &rows {
        println!(
            "| {fault:?} | {draws} | {right} of {draws} | {} |",
            wrong.len()
        );
    }
    for (fault, right, wrong) in rows {
        assert!(wrong.is_empty(), "{fault:?}: {wrong:?}");
        assert!(
            10 * right >= 9 * draws as usize,
            "{fault:?}: {right} of {draws} right first, below 90%"
        );
    }
}
