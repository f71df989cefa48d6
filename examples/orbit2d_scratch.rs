use autotune::model::catalog::{CatalogModel, ModelContext, orbit2d::Orbit2d};
use autotune::montecarlo::{Settings, run_generic};
use autotune::stats::ConsistencyReport;
use std::time::Instant;

fn main() {
    let text = std::fs::read_to_string("problems/orbit2d.toml").unwrap();
    let file: toml::Table = toml::from_str(&text).unwrap();
    let dt = file["dt"].as_float().unwrap();
    let mut table = file["model"].as_table().unwrap().clone();
    table.remove("name");
    let args: Vec<String> = std::env::args().collect();
    // optional overrides: key=value into [model] subtables, e.g. initial.pos_std=0.1
    for a in &args[1..] {
        if let Some((k, v)) = a.split_once('=') {
            if ["scale", "seed", "steps", "runs", "every"].contains(&k) {
                continue;
            }
            let (sec, key) = k.split_once('.').unwrap();
            let val: toml::Value =
                toml::from_str::<toml::Table>(&format!("v = {v}")).unwrap()["v"].clone();
            table
                .entry(sec.to_string())
                .or_insert(toml::Value::Table(Default::default()))
                .as_table_mut()
                .unwrap()
                .insert(key.to_string(), val);
        }
    }
    let get = |name: &str, d: f64| {
        args.iter()
            .find_map(|a| {
                a.strip_prefix(&format!("{name}="))
                    .map(|v| v.parse::<f64>().unwrap())
            })
            .unwrap_or(d)
    };
    let steps = get("steps", 600.0) as usize;
    let model = Orbit2d::from_table(&table, &ModelContext { dt, steps }).unwrap();
    let mut th = model.truth_values();
    let sc: Vec<f64> = args
        .iter()
        .find_map(|a| {
            a.strip_prefix("scale=")
                .map(|v| v.split(',').map(|x| x.parse().unwrap()).collect())
        })
        .unwrap_or(vec![1.0, 1.0]);
    th[0] *= sc[0];
    th[1] *= sc[1];
    let settings = Settings {
        runs: get("runs", 100.0) as usize,
        steps,
        seed: get("seed", 1.0) as u64,
        lags: 3,
    };
    let f = model.filter(&th);
    let t = Instant::now();
    let acc = run_generic(model.truth(), &f, &settings);
    let el = t.elapsed();
    let rep = ConsistencyReport::from_accumulator(
        &acc,
        0.05,
        &model.state_names(),
        &model.measurement_names(),
        true,
    );
    let nees = rep.nees.as_ref().unwrap();
    println!(
        "time {:.3} s  verdict {:?} diverged {}",
        el.as_secs_f64(),
        rep.verdict,
        rep.diverged_runs
    );
    println!(
        "ANEES {:.3} [{:.3},{:.3}] frac_in {:.3}",
        nees.time_average, nees.interval.lower, nees.interval.upper, nees.fraction_in_bounds
    );
    println!(
        "ANIS {:.3} [{:.3},{:.3}] target {:.3} frac_in {:.3} steps_with_data {}",
        rep.nis.time_average,
        rep.nis.interval.lower,
        rep.nis.interval.upper,
        rep.nis.target,
        rep.nis.fraction_in_bounds,
        rep.nis.steps_with_data
    );
    for c in &rep.state_components {
        println!(
            "  {} {:.3} [{:.3},{:.3}]",
            c.name, c.value, c.interval.lower, c.interval.upper
        );
    }
    for c in rep.measurement_components.iter().take(6) {
        println!(
            "  {} {:.3} [{:.3},{:.3}]",
            c.name, c.value, c.interval.lower, c.interval.upper
        );
    }
    if args.iter().any(|a| a == "white") {
        for w in rep.whiteness.iter().take(18) {
            println!(
                "  white {} lag {} rho {:.4} band {:.4}",
                w.component, w.lag, w.rho, w.band
            );
        }
        let (s2, c): (f64, f64) = (acc.nis_sq.iter().sum(), acc.nis_count.iter().sum());
        let d: f64 = acc.nis_dof.iter().sum();
        println!("  E[NIS^2]/step {:.3}, mean dof {:.3}", s2 / c, d / c);
        // per-run NIS totals variance
    }
    if args.iter().any(|a| a == "perstep") {
        for k in (0..steps).step_by(get("every", 10.0) as usize) {
            println!(
                "k {:4} nees {:?} nis {:?}",
                k + 1,
                nees.per_step[k].map(|v| (v * 100.0).round() / 100.0),
                rep.nis.per_step[k].map(|v| (v * 100.0).round() / 100.0)
            );
        }
    }
}
