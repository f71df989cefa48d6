//! The explanation's rules on values whose answer is known: when a trial is evidence, how
//! explanations rank and read, which fits are cases of a simpler one; and [`explain`] end to
//! end on mock experiments (a fixed parameter that is wrong, one that is right, a failure
//! more runs dispel). The hypotheses' trials on linear problems are tested by families of
//! random problems (tests/misfit/explain.rs).

use super::remedy::fmt_value;
use super::trials::{self, better, bounds, inexpressible};
use super::*;
use crate::experiment::{Hypothesized, LinearExperiment};
use crate::tune::tests::{Mock, settings};
use crate::tune::{LocalSearch, Scoring, Silent, Widening, tune};

fn trial(passed: usize, seeds: usize, band_low: usize) -> Trial {
    Trial {
        change: "fitting it".into(),
        status: TuneStatus::Consistent,
        passed,
        seeds,
        band_low,
        values: Vec::new(),
        evaluations: 10,
        score: 0.0,
        neutral: false,
        nis_only: false,
        recorded: false,
        same_as: None,
    }
}

fn fitting() -> Trial {
    trial(10, 10, 7)
}

fn explanation(h: Hypothesis, t: Option<Trial>) -> Explanation {
    Explanation {
        cause: Cause::Model(h),
        subject: "the sensors".into(),
        evidence: String::new(),
        remedy: "calibrate it".into(),
        untried: t.is_none().then(|| "no reason".into()),
        trial: t,
        added: 1,
    }
}

#[test]
fn a_trial_is_consistent_when_it_passes_as_often_as_a_consistent_filter() {
    assert!(trial(7, 10, 7).consistent());
    assert!(trial(10, 10, 7).consistent());
    assert!(!trial(6, 10, 7).consistent());
    // No seed tried: nothing shown.
    assert!(!trial(0, 0, 0).consistent());
}

#[test]
fn a_trial_is_evidence_when_it_fits_with_a_change_that_is_its_own() {
    assert!(fitting().fits());
    assert!(!trial(6, 10, 7).fits());
    let neutral = Trial {
        neutral: true,
        ..fitting()
    };
    assert!(neutral.consistent() && !neutral.fits());
    let nested = Trial {
        same_as: Some(Hypothesis::SensorBias),
        ..fitting()
    };
    assert!(nested.consistent() && !nested.fits());
}

#[test]
fn a_trials_outcome_says_what_it_showed() {
    let says = |t: &Trial, want: &str| {
        let o = t.outcome();
        assert!(o.starts_with(want), "{o:?} should start with {want:?}");
    };
    says(&fitting(), "makes the filter consistent (10 of 10");
    says(
        &trial(3, 10, 7),
        "does not make it consistent (3 of 10 fresh seeds pass; a consistent filter passes at least 7)",
    );
    says(
        &Trial {
            neutral: true,
            ..fitting()
        },
        "fits, but with its own parameters at their neutral values",
    );
    says(
        &Trial {
            same_as: Some(Hypothesis::SensorBias),
            ..fitting()
        },
        &format!("fits, as a case of {}", Hypothesis::SensorBias.words()),
    );
    let nis = Trial {
        nis_only: true,
        ..fitting()
    };
    assert!(nis.outcome().ends_with("(judged by the innovations alone)"));
    assert!(!fitting().outcome().contains("innovations"));
    // On a recording there are no fresh seeds: the record itself passes or fails.
    let on_record = |passed| Trial {
        recorded: true,
        ..trial(passed, 1, 1)
    };
    says(
        &on_record(1),
        "makes the filter consistent (the record passes)",
    );
    says(
        &on_record(0),
        "does not make it consistent (the record fails)",
    );
    assert!(!on_record(0).outcome().contains("at least"));
}

#[test]
fn an_explanation_ranks_by_its_trial_and_reads_as_one_line() {
    let h = Hypothesis::SensorGain;
    let fit = explanation(h, Some(fitting()));
    let miss = explanation(h, Some(trial(2, 10, 7)));
    let none = explanation(h, None);
    assert_eq!((fit.rank(), miss.rank(), none.rank()), (0, 1, 2));
    assert!(fit.fits() && !miss.fits() && !none.fits());
    let words = h.words();
    assert_eq!(
        fit.line(),
        format!(
            "{words} (the sensors): tried: fitting it {}; so: calibrate it",
            fitting().outcome()
        )
    );
    // The remedy only where the change fits; the evidence where there is some.
    let with_evidence = Explanation {
        evidence: "fitted gain_x = 1.2".into(),
        ..miss.clone()
    };
    assert_eq!(
        with_evidence.line(),
        format!(
            "{words} (the sensors): fitted gain_x = 1.2: tried: fitting it {}",
            trial(2, 10, 7).outcome()
        )
    );
    assert_eq!(
        none.line(),
        format!("{words} (the sensors): not tried: no reason")
    );
    assert_eq!(
        Cause::FixedParameter.words(),
        "a fixed parameter that is wrong"
    );
    assert_eq!(Cause::SearchBounds.words(), "a search bound");
    assert_eq!(Cause::Model(h).words(), words);
}

fn coloured(corr: f64, fits: bool) -> Explanation {
    let t = Trial {
        values: vec![("r_x".into(), 1.0), ("gm_corr_x".into(), corr)],
        ..if fits { fitting() } else { trial(2, 10, 7) }
    };
    explanation(Hypothesis::ColouredNoise, Some(t))
}

fn nested(mut out: Vec<Explanation>, steps: usize) -> Vec<Option<Hypothesis>> {
    mark_nested(&mut out, steps);
    out.iter()
        .map(|e| e.trial.as_ref().and_then(|t| t.same_as))
        .collect()
}

#[test]
fn coloured_noise_that_outlasts_the_run_beside_a_fitting_bias_is_a_bias() {
    let bias = || explanation(Hypothesis::SensorBias, Some(fitting()));
    let b = Some(Hypothesis::SensorBias);
    // 100 steps: a correlation above 1 − 1/100 outlasts the run.
    assert_eq!(nested(vec![bias(), coloured(0.991, true)], 100), [None, b]);
    assert_eq!(
        nested(vec![bias(), coloured(0.989, true)], 100),
        [None, None]
    );
    // Long runs: the correlation's bound 0.998 (its search's upper bound is 0.999).
    assert_eq!(
        nested(vec![bias(), coloured(0.9985, true)], 10_000),
        [None, b]
    );
    assert_eq!(
        nested(vec![bias(), coloured(0.9975, true)], 10_000),
        [None, None]
    );
    // Only beside a bias that fits, and only a coloured fit.
    let no_bias = explanation(Hypothesis::SensorBias, Some(trial(1, 10, 7)));
    assert_eq!(
        nested(vec![no_bias, coloured(0.999, true)], 100),
        [None, None]
    );
    let gain = explanation(Hypothesis::SensorGain, Some(fitting()));
    assert_eq!(nested(vec![gain, coloured(0.999, true)], 100), [None, None]);
    assert_eq!(
        nested(vec![bias(), coloured(0.999, false)], 100),
        [None, None]
    );
    // A coloured fit without a fitted correlation is no case of anything.
    let bare = explanation(Hypothesis::ColouredNoise, Some(fitting()));
    assert_eq!(nested(vec![bias(), bare], 100), [None, None]);
}

#[test]
fn a_measurement_matrix_beside_fitting_gains_is_a_gain() {
    let matrix = || explanation(Hypothesis::MeasurementMatrix, Some(fitting()));
    let gain = |fits: bool| {
        explanation(
            Hypothesis::SensorGain,
            Some(if fits { fitting() } else { trial(0, 10, 7) }),
        )
    };
    assert_eq!(
        nested(vec![gain(true), matrix()], 100),
        [None, Some(Hypothesis::SensorGain)]
    );
    assert_eq!(nested(vec![gain(false), matrix()], 100), [None, None]);
}

#[test]
fn values_read_in_a_few_significant_digits() {
    assert_eq!(super::remedy::with_unit(2.0, "m"), "2.000 m");
    assert_eq!(super::remedy::with_unit(2.0, ""), "2.000");
    for (v, want) in [
        (1.5, "1.500"),
        (0.0, "0.000"),
        (0.01, "0.010"),
        (99.5, "99.500"),
        (100.0, "1.000e2"),
        (-250.0, "-2.500e2"),
        (0.005, "5.000e-3"),
        (-0.005, "-5.000e-3"),
    ] {
        assert_eq!(fmt_value(v), want, "{v}");
    }
}

#[test]
fn what_a_filter_cannot_express_is_said_by_hypothesis() {
    assert!(inexpressible(Hypothesis::TimeStep).contains("no real logarithm"));
    assert!(inexpressible(Hypothesis::NoiseKind).contains("no real logarithm"));
    assert!(inexpressible(Hypothesis::MotionState).contains("no process-noise parameter"));
    for h in [Hypothesis::MeasurementMatrix, Hypothesis::FullR] {
        assert!(inexpressible(h).contains("one measurement component"));
    }
    assert_eq!(
        inexpressible(Hypothesis::SensorGain),
        "this filter cannot express it"
    );
}

/// Components 0 and 1 both follow p0 but are off by `e^{±1/2}` at every θ; component 2
/// follows p1 alone (truth 20): no value fits, and p1 matters only to component 2.
fn misfit(below_runs: usize) -> Mock {
    Mock::new(&[0.3, 20.0], &[&[1.0, 0.0], &[1.0, 0.0], &[0.0, 1.0]])
        .misfit(&[0.5, -0.5, 0.0], below_runs)
}

/// Component j follows p_j alone, no misfit; p1's truth `p1`.
fn separate_at(p1: f64) -> Mock {
    Mock::new(&[0.3, p1], &[&[1.0, 0.0], &[0.0, 1.0]])
}

fn separate() -> Mock {
    separate_at(20.0)
}

/// `mock` tuned from (1, 1) with both parameters free: consistent on the mocks that fit.
fn consistent_run(mock: &Mock) -> TuneResult {
    tune(
        mock,
        &[1.0, 1.0],
        &[false, false],
        mock.mc(),
        &quiet(),
        &Silent,
    )
    .expect("tuned")
}

fn quiet() -> TuneSettings {
    settings(Scoring::Exact).with_local(LocalSearch::Simplex)
}

/// Tune `mock` from `start` with p1 held fixed when `fix_p1`, and explain the result.
fn explained(mock: &Mock, start: &[f64], fix_p1: bool) -> (TuneResult, Vec<Explanation>) {
    let fixed = [false, fix_p1];
    let s = quiet();
    let r = tune(mock, start, &fixed, mock.mc(), &s, &Silent).expect("tuned");
    let e = explain(mock, &r, mock.mc(), &s).expect("explained");
    (r, e)
}

#[test]
fn a_wrong_fixed_parameter_is_the_cause_a_trial_proves() {
    // p1 held at 1 where the truth is beyond its bounds [1e-4, 1e4] on either side, but
    // inside the box widened ×100 that a freed parameter is searched in: nothing else can
    // make component 1 consistent.
    for truth in [3e4, 3e-6] {
        let mock = separate_at(truth);
        let (r, e) = explained(&mock, &[1.0, 1.0], true);
        assert_eq!(r.status, TuneStatus::Inconsistent, "{:?}", r.certificate);
        let first = &e[0];
        assert_eq!(first.cause, Cause::FixedParameter, "{e:#?}");
        assert!(first.fits(), "{first:#?}");
        let t = first.trial.as_ref().unwrap();
        let p1 = t.value("p1").unwrap();
        // The trial stops at J below 1e-5, where |ln(p1 / truth)| ≤ √(2e-5) = 4.5e-3.
        assert!((p1 / truth).ln().abs() < 4.5e-3, "{p1} vs {truth}");
        assert_eq!(
            first.remedy,
            format!("set p1 to about {} (it was fixed at 1.000)", fmt_value(p1))
        );
        // The model's changes cannot be made on a filter held as code: each listed,
        // untried, after the tried one.
        assert_eq!(e.len(), 1 + Hypothesis::ALL.len());
        for x in &e[1..] {
            assert!(
                matches!(x.cause, Cause::Model(_)) && x.trial.is_none(),
                "{x:#?}"
            );
            assert!(
                x.untried
                    .as_deref()
                    .unwrap()
                    .contains("as code, not as matrices it can change"),
                "{x:#?}"
            );
        }
    }
}

#[test]
fn a_right_fixed_parameter_freed_changes_nothing_and_is_no_evidence() {
    // p1 held at its truth; the misfit is elsewhere.
    let mock = misfit(usize::MAX);
    let (r, e) = explained(&mock, &[1.0, 20.0], true);
    assert_eq!(r.status, TuneStatus::Inconsistent);
    let freed = e
        .iter()
        .find(|x| x.cause == Cause::FixedParameter)
        .expect("p1 freed");
    let t = freed.trial.as_ref().unwrap();
    assert!(t.neutral && !freed.fits(), "{freed:#?}");
    assert!(e.iter().all(|x| !x.fits()), "{e:#?}");
}

#[test]
fn a_freed_fit_that_does_not_hold_is_polished_unless_the_user_chose_the_search() {
    // p1 held at 1 (truth 20) beside a misfit no value removes: freeing p1 comes far below
    // the unchanged filter's best but cannot hold, so the trial's full search is polished
    // by Levenberg–Marquardt (more evaluations), unless the user chose the local search.
    // Without the misfit the full search holds and nothing is polished.
    let calls = |mock: &Mock, local_set: bool| {
        let s = if local_set {
            quiet()
        } else {
            settings(Scoring::Exact)
        };
        let r = tune(
            mock,
            &[1.0, 1.0],
            &[false, true],
            mock.mc(),
            &quiet(),
            &Silent,
        )
        .unwrap();
        let before = mock.calls.load(std::sync::atomic::Ordering::SeqCst);
        let e = explain(mock, &r, mock.mc(), &s).expect("explained");
        let freed = e.iter().find(|x| x.cause == Cause::FixedParameter).unwrap();
        let n = mock.calls.load(std::sync::atomic::Ordering::SeqCst) - before;
        (n, freed.fits())
    };
    let off = Mock::new(&[0.3, 20.0], &[&[1.0, 0.0], &[1.0, 0.0], &[0.0, 1.0]])
        .misfit(&[0.5, -0.5, 0.0], usize::MAX);
    let (polished, fits) = calls(&off, false);
    assert!(!fits);
    let (plain, _) = calls(&off, true);
    assert!(polished > plain, "{polished} vs {plain} calls");
    let right = separate();
    let (unset, fits) = calls(&right, false);
    assert!(fits);
    assert_eq!(unset, calls(&right, true).0);
}

#[test]
fn a_misfit_more_runs_dispel_is_not_explained() {
    let mock = misfit(4 * misfit(0).mc().runs());
    let (r, e) = explained(&mock, &[1.0, 1.0], false);
    assert_eq!(r.status, TuneStatus::Undecided);
    assert!(e.is_empty(), "{e:#?}");
}

#[test]
fn a_run_needs_explaining_when_it_failed_or_had_to_widen_a_bound() {
    let mock = separate();
    let mut r = consistent_run(&mock);
    assert_eq!(r.status, TuneStatus::Consistent);
    assert!(!needed(&r));
    assert!(explain(&mock, &r, mock.mc(), &quiet()).unwrap().is_empty());
    for status in [TuneStatus::Inconsistent, TuneStatus::Undecided] {
        assert!(
            needed(&TuneResult {
                status,
                ..r.clone()
            }),
            "{status:?}"
        );
    }
    assert!(!needed(&TuneResult {
        status: TuneStatus::BudgetExhausted,
        ..r.clone()
    }));
    // A consistent run that widened a bound: the widening is the one explanation.
    r.widened.push(Widening {
        param: 1,
        from: (1e-4, 10.0),
        to: (1e-4, 1e4),
    });
    assert!(needed(&r));
    let e = explain(&mock, &r, mock.mc(), &quiet()).unwrap();
    assert_eq!(e.len(), 1);
    assert_eq!(e[0].cause, Cause::SearchBounds);
    assert!(e[0].fits(), "{:#?}", e[0]);
    assert_eq!(
        e[0].evidence,
        "p1 stopped at its upper bound 10.000 of [1.000e-4, 10.000]"
    );
    assert_eq!(bounds(&mock, &r).len(), 1);
}

#[test]
fn a_trial_that_passes_is_better_than_one_that_does_not_whatever_the_scores() {
    let mock = separate();
    let r = consistent_run(&mock);
    let with = |passed: usize, j: f64| {
        let mut t = r.clone();
        t.confirmation.passed = passed;
        t.confirmation.band_low = 7;
        t.objective_final.total = j;
        t
    };
    use std::cmp::Ordering::*;
    assert_eq!(better(&with(8, 5.0), &with(6, 0.1)), Less);
    assert_eq!(better(&with(6, 0.1), &with(8, 5.0)), Greater);
    assert_eq!(better(&with(8, 0.1), &with(9, 5.0)), Less);
    assert_eq!(better(&with(2, 0.3), &with(3, 0.2)), Greater);
}

#[test]
fn fits_come_first_by_fewest_added_parameters_then_score_and_untried_last() {
    let fit = |h: Hypothesis, added: usize, score: f64| Explanation {
        added,
        ..explanation(h, Some(Trial { score, ..fitting() }))
    };
    let mut out = vec![
        explanation(Hypothesis::TimeStep, None),
        // Tried, not fitting: kept in the trials' order whatever their sizes and scores.
        Explanation {
            added: 2,
            ..explanation(
                Hypothesis::Delay(1),
                Some(Trial {
                    score: 5.0,
                    ..trial(0, 10, 7)
                }),
            )
        },
        fit(Hypothesis::ColouredNoise, 2, 0.001),
        explanation(Hypothesis::Delay(2), Some(trial(1, 10, 7))),
        fit(Hypothesis::SensorGain, 1, 0.3),
        fit(Hypothesis::SensorBias, 2, 0.0001),
    ];
    order(&mut out);
    let causes: Vec<Cause> = out.iter().map(|e| e.cause).collect();
    use Hypothesis::*;
    assert_eq!(
        causes,
        [
            SensorGain,
            SensorBias,
            ColouredNoise,
            Delay(1),
            Delay(2),
            TimeStep
        ]
        .map(Cause::Model)
    );
}

#[test]
fn a_trial_weighs_the_first_moments_unless_the_run_already_did() {
    let mock = separate();
    let r = consistent_run(&mock);
    let bias_of = |s: &TuneSettings| {
        trials::Trials {
            experiment: &mock,
            result: &r,
            mc: mock.mc(),
            settings: s,
        }
        .settings_for()
        .weights()
        .bias
    };
    assert_eq!(bias_of(&quiet()), 1.0);
    let mut w = quiet().weights();
    w.bias = 2.5;
    assert_eq!(bias_of(&quiet().with_weights(w).unwrap()), 2.5);
}

/// cv2d's model, built here (the problem layer is above this one): two decoupled
/// constant-velocity axes x and y at dt = 1, position sensors x and y, CWNA inputs
/// q_accel_x and q_accel_y, sensor noises r_pos_x and r_pos_y.
fn cv2d() -> LinearExperiment {
    use crate::experiment::{Definition, FilterModel, Info, Source};
    use crate::model::LinearGaussianModel;
    use crate::montecarlo::McConfig;
    use crate::params::{Coef, CovModel, CovTerm, ParamDef, ParamSpace, cwna_block, embed};
    use nalgebra::{DMatrix, DVector};
    let cv = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]);
    let mut f = DMatrix::zeros(4, 4);
    f.view_mut((0, 0), (2, 2)).copy_from(&cv);
    f.view_mut((2, 2), (2, 2)).copy_from(&cv);
    let mut h = DMatrix::zeros(2, 4);
    h[(0, 0)] = 1.0;
    h[(1, 2)] = 1.0;
    let (q, r) = ([0.5, 0.1], [1.0, 4.0]);
    let q_basis = |a: usize| embed(4, &[2 * a, 2 * a + 1], &cwna_block(1.0));
    let r_basis = |a: usize| embed(2, &[a], &DMatrix::from_element(1, 1, 1.0));
    let big_q = q_basis(0) * q[0] + q_basis(1) * q[1];
    let big_r = DMatrix::from_diagonal(&DVector::from_column_slice(&r));
    let p0 = DMatrix::identity(4, 4) * 10.0;
    let x0 = DVector::zeros(4);
    let params = ["q_accel_x", "q_accel_y", "r_pos_x", "r_pos_y"]
        .iter()
        .zip(q.iter().chain(&r))
        .map(|(n, v)| ParamDef::new(n, *v))
        .collect();
    let terms = |basis: &dyn Fn(usize) -> DMatrix<f64>, first: usize| {
        (0..2)
            .map(|a| CovTerm {
                coef: Coef::Param(first + a),
                basis: basis(a),
            })
            .collect()
    };
    LinearExperiment::new(
        Definition {
            info: Info {
                name: "cv2d".into(),
                description: String::new(),
                source: Source::Program {
                    name: "cv2d".into(),
                },
            },
            params: ParamSpace { params },
            state_names: ["px", "vx", "py", "vy"].map(String::from).to_vec(),
            measurement_names: vec!["x".into(), "y".into()],
            mc: McConfig::new(50, 100).expect("valid"),
        },
        LinearGaussianModel::new(f.clone(), h.clone(), big_q, big_r, x0.clone(), p0.clone())
            .expect("a valid truth"),
        FilterModel {
            F: f,
            H: h,
            x0,
            P0: p0,
            q: CovModel {
                dim: 4,
                terms: terms(&q_basis, 0),
            },
            r: CovModel {
                dim: 2,
                terms: terms(&r_basis, 2),
            },
            map: None,
        },
    )
}

/// What a fitted hypothesis says on cv2d ([`cv2d`]), read off hand-set values: each added
/// parameter at its neutral value except `moved`.
fn reading(h: Hypothesis, moved: &[&str]) -> (String, String, String) {
    let base = cv2d();
    let lin = &base;
    let theta = lin.params().values();
    let e = Hypothesized::new(lin, h, &theta).expect("cv2d can express it");
    let values = e
        .added()
        .iter()
        .map(|a| {
            assert!(a.is_neutral(a.neutral), "{}", a.def.name);
            let v = if !moved.contains(&a.def.name.as_str()) {
                a.neutral
            } else {
                a.negligible.map_or(a.neutral * 1.5, |t| t * 1e3)
            };
            (a.def.name.clone(), v)
        })
        .collect();
    let t = Trial {
        values,
        ..fitting()
    };
    super::remedy::read(&e, &t)
}

#[test]
fn a_fit_names_where_the_change_is_and_what_to_do() {
    use Hypothesis::*;
    let (subject, says, remedy) = reading(SensorGain, &["gain_x"]);
    assert_eq!(subject, "the sensors: x");
    assert_eq!(says, "fitted gain_x = 1.500, gain_y = 1.000");
    assert!(remedy.starts_with("the readings of x scale"), "{remedy}");
    let (subject, _, _) = reading(SensorGain, &[]);
    assert_eq!(subject, "the sensors");
    let (subject, _, remedy) = reading(SensorBias, &["bias_mean_x", "bias_var_y"]);
    assert_eq!(subject, "the sensors: x, y");
    assert!(
        remedy.contains("(x: constant in every run; y: drawn anew in every run)"),
        "{remedy}"
    );
    let (_, _, remedy) = reading(SensorBias, &["bias_mean_y", "bias_var_y"]);
    assert!(
        remedy.contains("(y: a constant part and a part drawn per run)"),
        "{remedy}"
    );
    let (subject, _, remedy) = reading(ColouredNoise, &["gm_var_y", "gm_corr_y"]);
    assert_eq!(subject, "the sensors: y");
    assert!(
        remedy.starts_with("the noise of y is correlated"),
        "{remedy}"
    );
    let (subject, _, remedy) = reading(MotionState, &["singer_drive_q_accel_x"]);
    assert_eq!(subject, "the motion model: the input of q_accel_x");
    assert!(remedy.starts_with("add the state"), "{remedy}");
    let (subject, says, remedy) = reading(TimeStep, &["dt_scale"]);
    assert_eq!(subject, "the motion model: F and Q");
    assert_eq!(says, "fitted dt_scale = 1.500");
    assert!(
        remedy.starts_with("build F and Q for a step 1.500 times"),
        "{remedy}"
    );
    let (subject, says, remedy) = reading(Delay(2), &[]);
    assert_eq!(
        (subject.as_str(), says.as_str()),
        ("the sensors: every reading", "")
    );
    assert!(remedy.contains("2 steps back"), "{remedy}");
    let (_, _, remedy) = reading(Delay(1), &[]);
    assert!(remedy.contains("1 step back:"), "{remedy}");
    let (subject, _, remedy) = reading(FullR, &["rho_x_y"]);
    assert_eq!(subject, "the sensors: R");
    assert!(remedy.ends_with("(rho_x_y)"), "{remedy}");
    let (subject, _, remedy) = reading(InitialCovariance, &["p0_scale"]);
    assert_eq!(subject, "the start: P0");
    assert_eq!(remedy, "scale the filter's P0 by 1.500");
    let (subject, _, remedy) = reading(NoiseKind, &[]);
    assert_eq!(subject, "the motion model: Q's kind");
    assert!(remedy.starts_with("build Q as the other kind"), "{remedy}");
    let (subject, _, _) = reading(MeasurementMatrix, &["gain_y"]);
    assert_eq!(subject, "the sensors: H");
}
