mod common;
use autotune::experiment::Experiment;
use autotune::tune::{Silent, TuneSettings, tune};
#[test]
#[ignore]
fn measure_catalog_spread() {
    for name in ["ctrv", "orbit2d"] {
        let p = common::load(name);
        let truth = common::truth_values(&p);
        let fixed: Vec<bool> = p.params().params.iter().map(|q| q.fixed).collect();
        let settings = TuneSettings::default()
            .with_global_points(8)
            .unwrap()
            .with_max_evals(120)
            .unwrap()
            .with_max_seconds(600.0)
            .unwrap()
            .with_search_runs(p.mc().runs())
            .unwrap();
        for seed in [1u64, 2, 3, 4, 5, 6] {
            for factor in [10.0, 0.1] {
                let start: Vec<f64> = truth
                    .iter()
                    .zip(&fixed)
                    .map(|(&v, &f)| if f { v } else { v * factor })
                    .collect();
                let mc = p.mc().with_seed(seed);
                let r = tune(&p, &start, &fixed, &mc, &settings, &Silent).unwrap();
                let errs: Vec<String> = r
                    .tuned
                    .iter()
                    .zip(&truth)
                    .zip(&fixed)
                    .filter(|(_, f)| !**f)
                    .map(|((t, v), _)| format!("{:+.4}", (t / v).ln()))
                    .collect();
                eprintln!(
                    "SPREAD {name} seed {seed} x{factor}: {:?} {} evals ln-err {}",
                    r.status,
                    r.evaluations,
                    errs.join(" ")
                );
            }
        }
    }
}
