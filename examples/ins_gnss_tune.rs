//! Scratch check of the `ins_gnss` catalog model: time one Monte Carlo evaluation of the
//! shipped problem, report the check at the truth's noise and at Q × 0.01, and tune from
//! 10x off in every free parameter (both directions).
//!
//! `cargo run --release --example ins_gnss_tune -- [check|one|parts|tune-up|tune-down|all]`
//! (`one`: three evaluations at the truth; `parts`: µs per step of truth and filter alone).
//! Tuning uses 200 evaluations, 4 global points per parameter, 2 local starts and
//! `SEARCH_RUNS_FACTOR` × N search runs (default 2).

use std::time::Instant;

use autotune::model::catalog::{ModelContext, ins_gnss::ENTRY};
use autotune::montecarlo::{Settings, run_generic};
use autotune::params::{ParamDef, ParamSpace};
use autotune::problem::McConfig;
use autotune::stats::ConsistencyReport;
use autotune::tune::{CustomModel, Silent, TuneSettings, tune};

fn main() {
    let mode = std::env::args().nth(1).unwrap_or_else(|| "check".into());
    let text = std::fs::read_to_string("problems/ins_gnss.toml").expect("problem file");
    let file: toml::Table = toml::from_str(&text).expect("toml");
    let dt = file["dt"].as_float().expect("dt");
    let mcf = file["montecarlo"].as_table().expect("montecarlo");
    let runs = mcf["runs"].as_integer().expect("runs") as usize;
    let steps = mcf["steps"].as_integer().expect("steps") as usize;
    let mut table = file["model"].as_table().expect("model").clone();
    table.remove("name");
    let model = (ENTRY.build)(&table, &ModelContext { dt, steps }).expect("build");
    let truth = model.truth_values();
    let sn = model.state_names();
    let mn = model.measurement_names();

    let check = |theta: &[f64], seed: u64, n: usize| {
        let f = model.filter(theta);
        let t0 = Instant::now();
        let acc = run_generic(
            model.truth(),
            &f,
            &Settings {
                runs: n,
                steps,
                seed,
                lags: 3,
            },
        );
        let secs = t0.elapsed().as_secs_f64();
        (
            ConsistencyReport::from_accumulator(&acc, 0.05, &sn, &mn, true),
            secs,
        )
    };
    let show = |label: &str, r: &ConsistencyReport, secs: f64| {
        let ne = r.nees.as_ref().expect("nees");
        println!(
            "{label}: {:.3} s, verdict {:?}, ANEES {:.3} in [{:.3}, {:.3}], ANIS {:.3} in [{:.3}, {:.3}], diverged {}",
            secs,
            r.verdict,
            ne.time_average,
            ne.interval.lower,
            ne.interval.upper,
            r.nis.time_average,
            r.nis.interval.lower,
            r.nis.interval.upper,
            r.diverged_runs
        );
        let comps: Vec<String> = r
            .state_components
            .iter()
            .chain(&r.measurement_components)
            .map(|c| format!("{} {:.2}", c.name, c.value))
            .collect();
        println!("  components: {}", comps.join(", "));
    };

    if mode == "parts" {
        use autotune::filter::Filter;
        use autotune::model::Measurement;
        let tm = model.truth();
        let f = model.filter(&truth);
        let mut rng = autotune::montecarlo::run_rng(1, 0);
        let mut xs = Vec::new();
        let mut us = Vec::new();
        let mut ms = Vec::new();
        let t0 = Instant::now();
        for _ in 0..10 {
            let mut x = tm.initial_state(&mut rng);
            xs.clear();
            us.clear();
            ms.clear();
            for k in 1..=steps {
                x = tm.propagate(k, &x, &mut rng);
                us.push(tm.input(k, &x, &mut rng).expect("input"));
                let mut m: Vec<Measurement> = Vec::new();
                tm.measure(k, &x, &mut rng, &mut m);
                ms.push(m);
                xs.push(x.clone());
            }
        }
        println!(
            "truth: {:.2} us/step",
            t0.elapsed().as_secs_f64() * 1e6 / (10 * steps) as f64
        );
        let t0 = Instant::now();
        for _ in 0..10 {
            let mut est = f.initial();
            for k in 1..=steps {
                f.predict_with_input(k, &mut est, &us[k - 1])
                    .expect("predict");
                for m in &ms[k - 1] {
                    f.update(k, &mut est, m).expect("update");
                }
                let _e = f.state_error(&xs[k - 1], &est.x);
            }
        }
        println!(
            "filter: {:.2} us/step",
            t0.elapsed().as_secs_f64() * 1e6 / (10 * steps) as f64
        );
    }
    if mode == "one" {
        for _ in 0..3 {
            let (r, s) = check(&truth, 1, runs);
            show("truth", &r, s);
        }
    }
    if mode == "check" || mode == "all" {
        for seed in [1u64, 2, 3] {
            let (r, s) = check(&truth, seed, runs);
            show(&format!("truth seed {seed}"), &r, s);
        }
        let mut low = truth.clone();
        for v in low.iter_mut().take(6) {
            *v *= 0.01;
        }
        let (r, s) = check(&low, 1, runs);
        show("Q x 0.01", &r, s);
        for (i, p) in ENTRY.params.iter().enumerate().take(6) {
            for f in [0.1, 10.0] {
                let mut th = truth.clone();
                th[i] *= f;
                let (r, s) = check(&th, 1, runs);
                show(&format!("{} x{f}", p.name), &r, s);
            }
        }
    }
    for (dir, factor) in [("tune-up", 10.0), ("tune-down", 0.1)] {
        if mode != dir && mode != "all" {
            continue;
        }
        let params = ParamSpace {
            params: ENTRY
                .params
                .iter()
                .enumerate()
                .map(|(i, p)| ParamDef {
                    name: p.name.into(),
                    value: truth[i],
                    lower: truth[i] * 1e-3,
                    upper: truth[i] * 1e3,
                    fixed: i >= 6,
                    unit: p.unit.into(),
                    about: p.about.into(),
                })
                .collect(),
        };
        let start: Vec<f64> = truth
            .iter()
            .enumerate()
            .map(|(i, v)| if i < 6 { v * factor } else { *v })
            .collect();
        let fixed: Vec<bool> = (0..truth.len()).map(|i| i >= 6).collect();
        let cm = CustomModel::new(
            model.truth(),
            |th: &[f64]| model.filter(th),
            params,
            sn.clone(),
            mn.clone(),
        );
        let mc = McConfig {
            runs,
            steps,
            seed: 1,
            alpha: 0.05,
            lags: 3,
        };
        let settings = TuneSettings {
            max_seconds: 1500.0,
            max_evals: 200,
            global_points_per_param: 4,
            starts: 2,
            search_runs: Some(
                std::env::var("SEARCH_RUNS_FACTOR")
                    .ok()
                    .and_then(|v| v.parse::<usize>().ok())
                    .unwrap_or(2)
                    * runs,
            ),
            ..TuneSettings::default()
        };
        let t0 = Instant::now();
        let res = tune(&cm, &start, &fixed, &mc, &settings, &Silent).expect("tune");
        println!(
            "{dir}: status {:?}, {} evaluations, {:.0} s wall ({:.0} s reported)",
            res.status,
            res.evaluations,
            t0.elapsed().as_secs_f64(),
            res.seconds
        );
        for (i, p) in ENTRY.params.iter().enumerate().take(6) {
            println!(
                "  {:14} start {:.3e} tuned {:.3e} truth {:.3e} ({:+.0}%) resolution {:?}",
                p.name,
                start[i],
                res.tuned[i],
                truth[i],
                100.0 * (res.tuned[i] / truth[i] - 1.0),
                res.resolution[i].factor
            );
        }
        show("  confirmation", &res.after, 0.0);
    }
}
