//! Tune the catalog's `orbit2d` EKF from 10x off in both free parameters (all x10, then all
//! x0.1), and report where the process-noise PSDs land relative to the truth's.
//!
//! Run with `cargo run --release --example orbit2d_tune [up|down|both] [default]`. It exits non-zero
//! unless every tuned filter passes the consistency gate on fresh seeds.

use autotune::model::catalog::{CatalogModel, ModelContext, orbit2d};
use autotune::params::{ParamDef, ParamSpace};
use autotune::problem::McConfig;
use autotune::tune::{CustomModel, Silent, TuneSettings, TuneStatus, tune};

fn main() {
    let text = std::fs::read_to_string("problems/orbit2d.toml").expect("problems/orbit2d.toml");
    let file: toml::Table = toml::from_str(&text).expect("valid TOML");
    let dt = file["dt"].as_float().expect("dt");
    let mc = &file["montecarlo"];
    let int = |k: &str| mc[k].as_integer().expect("integer") as usize;
    let mc = McConfig {
        runs: int("runs"),
        steps: int("steps"),
        seed: int("seed") as u64,
        alpha: mc["alpha"].as_float().expect("alpha"),
        lags: 3,
    };
    let mut table = file["model"].as_table().expect("[model]").clone();
    table.remove("name");
    let model = orbit2d::Orbit2d::from_table(
        &table,
        &ModelContext {
            dt,
            steps: mc.steps,
        },
    )
    .expect("valid [model]");
    let truth = model.truth_values();
    let fixed: Vec<bool> = orbit2d::ENTRY
        .params
        .iter()
        .map(|p| p.noise == autotune::model::catalog::NoiseKind::Measurement)
        .collect();
    let which = std::env::args().nth(1).unwrap_or_else(|| "both".into());
    let factors: Vec<f64> = match which.as_str() {
        "up" => vec![10.0],
        "down" => vec![0.1],
        _ => vec![10.0, 0.1],
    };
    let mut ok = true;
    for factor in factors {
        let start: Vec<f64> = truth
            .iter()
            .zip(&fixed)
            .map(|(v, f)| if *f { *v } else { v * factor })
            .collect();
        let params = ParamSpace {
            params: orbit2d::ENTRY
                .params
                .iter()
                .zip(&start)
                .zip(&fixed)
                .map(|((p, &v), &f)| ParamDef {
                    name: p.name.into(),
                    value: v,
                    lower: v / 1e4,
                    upper: v * 1e4,
                    fixed: f,
                    unit: p.unit.into(),
                    about: p.about.into(),
                })
                .collect(),
        };
        let custom = CustomModel::new(
            model.truth(),
            |th: &[f64]| model.filter(th),
            params,
            model.state_names(),
            model.measurement_names(),
        );
        // `default` as second argument: the library's default search (4N runs per
        // evaluation, 120 s budget), as the CLI would run it.
        let settings = if std::env::args().nth(2).as_deref() == Some("default") {
            TuneSettings::default()
        } else {
            TuneSettings {
                max_evals: 300,
                global_points_per_param: 6,
                starts: 2,
                search_runs: Some(2 * mc.runs),
                max_seconds: 600.0,
                ..TuneSettings::default()
            }
        };
        let r = tune(&custom, &start, &fixed, &mc, &settings, &Silent).expect("valid settings");
        println!(
            "start x{factor}: {:?} after {} evaluations in {:.1} s",
            r.status, r.evaluations, r.seconds
        );
        for (i, p) in orbit2d::ENTRY.params.iter().enumerate() {
            if !fixed[i] {
                println!(
                    "  {}: start {:.3e}, tuned {:.3e}, truth {:.3e} ({:+.1}%), resolution {:?}",
                    p.name,
                    start[i],
                    r.tuned[i],
                    truth[i],
                    100.0 * (r.tuned[i] / truth[i] - 1.0),
                    r.resolution[i].factor
                );
            }
        }
        let a = &r.after;
        println!(
            "  confirmation (seed {}): ANEES {:.3} in [{:.3}, {:.3}], ANIS {:.3} in [{:.3}, {:.3}]: {}",
            r.confirm_seed,
            a.nees.as_ref().map_or(f64::NAN, |s| s.time_average),
            a.nees.as_ref().map_or(f64::NAN, |s| s.interval.lower),
            a.nees.as_ref().map_or(f64::NAN, |s| s.interval.upper),
            a.nis.time_average,
            a.nis.interval.lower,
            a.nis.interval.upper,
            a.verdict.describe()
        );
        ok &= r.status == TuneStatus::Consistent;
    }
    if !ok {
        std::process::exit(1);
    }
}
