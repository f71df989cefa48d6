//! Truth tapes (issue 25): a seed set's truth simulated once and replayed to every filter
//! gives the same sums, bit for bit, as simulating it at every evaluation: for each catalog
//! model (a UKF with a changing sensor schedule, an EKF on an RK4 orbit, an error-state INS
//! whose truth hands the filter IMU inputs), for runs the truth ends early (overflow) and
//! runs a filter ends early (divergence), and past the cache's memory limit (no tape).

use autotune::SimRng;
use autotune::internals::catalog::{self, CatalogModel, ModelContext};
use autotune::internals::filter::{Filter, KalmanFilter};
use autotune::internals::measurement::Measurement;
use autotune::internals::model::TruthModel;
use autotune::internals::montecarlo::{
    McConfig, RunOptions, Share, ShareOf, TruthCache, TruthTape, run_generic, run_generic_cached,
};
use autotune::internals::stats::Accumulator;
use nalgebra::{DMatrix, DVector};

/// The shipped catalog problem `name`'s model and Monte Carlo test.
fn shipped(name: &str) -> (Box<dyn CatalogModel>, McConfig) {
    let path = format!("{}/problems/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    let file: toml::Table = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let mut table = file["model"].as_table().unwrap().clone();
    let entry = catalog::find(table.remove("name").unwrap().as_str().unwrap()).unwrap();
    let mc = file["montecarlo"].as_table().unwrap();
    let steps = mc["steps"].as_integer().unwrap() as usize;
    let context = ModelContext {
        dt: file["dt"].as_float().unwrap(),
        steps,
    };
    let model = (entry.build)(&table, &context).unwrap();
    let mc = McConfig::new(1, steps)
        .unwrap()
        .with_seed(mc["seed"].as_integer().unwrap() as u64);
    (model, mc)
}

/// Sums compared field by field, so a failure names what differs.
fn assert_same(a: &Accumulator, b: &Accumulator, what: &str) {
    assert_eq!(a.runs(), b.runs(), "{what}: runs");
    assert_eq!(a, b, "{what}: the sums differ");
}

/// Issue 26: each share of three (a shard, an MPI rank) with its own cache, evaluated
/// three times (simulating, taping its runs, replaying them): its chunks merged with the
/// other shares' are the one-process sums, bit for bit, and its tape holds its runs alone.
#[test]
fn shares_tape_their_own_runs_and_merge_to_the_whole() {
    let (model, mc) = shipped("ctrv");
    let mc = mc.with_runs(64 * 4 + 7).unwrap();
    let filter = model.filter(&model.truth_values());
    let whole = run_generic(model.truth(), &filter, &mc);
    let caches: Vec<TruthCache> = (0..3).map(|_| TruthCache::default()).collect();
    for evaluation in 0..3 {
        let parts = std::sync::Mutex::new(Vec::new());
        let sink = |c: usize, sums: Accumulator| parts.lock().unwrap().push((c, sums));
        for (i, cache) in caches.iter().enumerate() {
            let share = Share::new(i, 3).unwrap();
            let options = RunOptions {
                share: Some(ShareOf { share, sink: &sink }),
                ..RunOptions::default()
            };
            let rest = run_generic_cached(model.truth(), &filter, &mc, options, cache);
            assert_eq!(rest.runs(), 0, "a share's own sums go to its sink");
        }
        let parts = parts.into_inner().unwrap();
        let chunks: Vec<usize> = parts.iter().map(|(c, _)| *c).collect();
        assert_eq!(chunks.len(), 5, "{chunks:?}");
        let empty = Accumulator::new(mc.steps(), 5, 5, mc.lags());
        let merged = Share::merge(mc.runs(), empty, parts).unwrap();
        assert_same(
            &whole,
            &merged,
            &format!("shares merged, evaluation {evaluation}"),
        );
    }
    // The first share holds chunks 0 and 3 (128 runs), the third chunk 2 (64).
    let (first, third) = (caches[0].bytes(), caches[2].bytes());
    assert!(first > 0 && third > 0);
    let ratio = first as f64 / third as f64;
    assert!((ratio - 2.0).abs() < 0.1, "{first} vs {third} bytes");
}

/// Issue 41: an MPI rank's evaluations of one seed set dealt by runs, at run counts that
/// slice each chunk differently (the last chunk of 200 runs holds 8, of 800 runs 32), and
/// by chunks: each share's tape gains the runs it lacks, the runs merged in run order are
/// the one-process sums bit for bit at every evaluation, and every share counts its tape
/// usage as the one process does.
#[test]
fn shares_dealt_by_runs_tape_the_runs_each_deal_gives_them_and_count_as_one_process() {
    let (model, mc) = shipped("ctrv");
    let filter = model.filter(&model.truth_values());
    let one = TruthCache::default();
    let caches: Vec<TruthCache> = (0..3).map(|_| TruthCache::default()).collect();
    for (k, (runs, by_runs)) in [
        (800, false),
        (800, false),
        (200, true),
        (300, true),
        (200, true),
    ]
    .into_iter()
    .enumerate()
    {
        let mc = mc.with_runs(runs).unwrap();
        let whole = run_generic_cached(model.truth(), &filter, &mc, Default::default(), &one);
        let parts = std::sync::Mutex::new(Vec::new());
        let sink = |c: usize, sums: Accumulator| parts.lock().unwrap().push((c, sums));
        for (i, cache) in caches.iter().enumerate() {
            let share = if by_runs {
                Share::runs(i, 3).unwrap()
            } else {
                Share::new(i, 3).unwrap()
            };
            let options = RunOptions {
                share: Some(ShareOf { share, sink: &sink }),
                ..RunOptions::default()
            };
            run_generic_cached(model.truth(), &filter, &mc, options, cache);
            assert_eq!(cache.usage(), one.usage(), "evaluation {k}, share {i}");
        }
        let mut parts = parts.into_inner().unwrap();
        let empty = || Accumulator::new(mc.steps(), 5, 5, mc.lags());
        if by_runs {
            parts = Share::merge_runs(mc.runs(), empty, parts).unwrap();
        }
        let merged = Share::merge(mc.runs(), empty(), parts).unwrap();
        assert_same(&whole, &merged, &format!("evaluation {k} ({runs} runs)"));
    }
    // 800, 800 (taped), then 200, 300 and 200 from the tape, one process and shares alike.
    let usage = one.usage();
    assert_eq!((usage.simulated, usage.replayed), (2, 3), "{usage:?}");
}

#[test]
fn replayed_catalog_truth_gives_the_simulated_sums_bit_for_bit() {
    for name in ["ctrv", "orbit2d", "ins_gnss"] {
        let (model, mc) = shipped(name);
        // Two chunks, the second partial; a shorter horizon for the INS's 900 steps.
        let mc = mc.with_runs(70).unwrap();
        let mc = mc.with_steps(mc.steps().min(300)).unwrap();
        let truth = model.truth_values();
        let other: Vec<f64> = truth.iter().map(|v| v * 3.0).collect();
        let cache = TruthCache::default();
        for (k, theta) in [&truth, &truth, &other, &truth].into_iter().enumerate() {
            let filter = model.filter(theta);
            let simulated = run_generic(model.truth(), &filter, &mc);
            let cached =
                run_generic_cached(model.truth(), &filter, &mc, Default::default(), &cache);
            assert_same(&simulated, &cached, &format!("{name}, evaluation {k}"));
            // The first evaluation of a seed set simulates; the second records the tape.
            assert_eq!(
                cache.bytes() > 0,
                k > 0,
                "{name}, evaluation {k}: tape held"
            );
        }
        // Fewer runs replay from the same tape; more runs extend it.
        for runs in [10, 140] {
            let mc = mc.with_runs(runs).unwrap();
            let filter = model.filter(&other);
            let simulated = run_generic(model.truth(), &filter, &mc);
            let cached =
                run_generic_cached(model.truth(), &filter, &mc, Default::default(), &cache);
            assert_same(&simulated, &cached, &format!("{name}, {runs} runs"));
        }
        let tape = TruthTape::record(model.truth(), mc.seed(), mc.steps(), 140);
        assert!(tape.covers(&mc.with_runs(140).unwrap(), Share::WHOLE));
        assert!(!tape.covers(&mc.with_runs(141).unwrap(), Share::WHOLE));
        assert!(!tape.covers(
            &mc.with_seed(mc.seed() + 1).with_runs(10).unwrap(),
            Share::WHOLE
        ));
        // The tape holds at least its numbers: T × (n_x + measurement components).
        assert!(tape.bytes() >= 140 * mc.steps() * 8 * model.truth().n_x());
    }
}

/// A scalar random walk that overflows to +∞ at step `stop` in the runs whose state is
/// then above 0.5.
struct Blowup {
    stop: usize,
}

impl TruthModel for Blowup {
    fn n_x(&self) -> usize {
        1
    }
    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        DVector::from_element(
            1,
            rand_distr::Distribution::sample(&rand_distr::StandardNormal, rng),
        )
    }
    fn propagate(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        let w: f64 = rand_distr::Distribution::sample(&rand_distr::StandardNormal, rng);
        // A rule on the state keeps the overflow a property of the run's stream, as a real
        // one is.
        if k == self.stop && x[0] > 0.5 {
            return DVector::from_element(1, f64::INFINITY);
        }
        DVector::from_element(1, x[0] + w)
    }
    fn measure(&self, _k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        let v: f64 = rand_distr::Distribution::sample(&rand_distr::StandardNormal, rng);
        out.push(Measurement {
            sensor: 0,
            z: DVector::from_element(1, x[0] + v),
        });
    }
}

/// A scalar Kalman filter for [`Blowup`] with process noise `q` and measurement noise `r`.
#[allow(non_snake_case)]
fn walk_filter(q: f64, r: f64) -> impl Filter {
    let one = DMatrix::from_element(1, 1, 1.0);
    KalmanFilter {
        F: one.clone(),
        H: one.clone(),
        Q: DMatrix::from_element(1, 1, q),
        R: DMatrix::from_element(1, 1, r),
        x0: DVector::zeros(1),
        P0: one,
    }
}

#[test]
fn runs_the_truth_or_the_filter_ends_replay_as_they_simulate() {
    let truth = Blowup { stop: 17 };
    let mc = McConfig::new(100, 40).unwrap().with_seed(5);
    let cache = TruthCache::default();
    // q = -1 makes P indefinite after the first prediction: every run's filter fails.
    for (q, r) in [(1.0, 1.0), (0.3, 2.0), (-1.0, 1.0), (1.0, 1.0)] {
        let f = walk_filter(q, r);
        let simulated = run_generic(&truth, &f, &mc);
        let cached = run_generic_cached(&truth, &f, &mc, Default::default(), &cache);
        assert_same(&simulated, &cached, &format!("q = {q}, r = {r}"));
        if q > 0.0 {
            // x₁₆ ~ N(0, 17): P(x₁₆ > 0.5) = 0.45, so 45 of 100 runs expected (binomial sd 5).
            let overflowed = simulated.truth_overflow_runs();
            assert!(
                (30..=60).contains(&overflowed),
                "q = {q}: {overflowed} of 100 runs overflowed at step 17"
            );
        }
    }
    assert!(cache.bytes() > 0);
}

#[test]
fn a_tape_beyond_the_memory_limit_is_never_recorded() {
    let truth = Blowup { stop: usize::MAX };
    let mc = McConfig::new(200, 50).unwrap().with_seed(9);
    // One run's tape is 50 states and 50 one-number measurements: well over 1 kB.
    let cache = TruthCache::with_limit(1000);
    let f = walk_filter(1.0, 1.0);
    for _ in 0..3 {
        let cached = run_generic_cached(&truth, &f, &mc, Default::default(), &cache);
        assert_same(&run_generic(&truth, &f, &mc), &cached, "over the limit");
        assert_eq!(cache.bytes(), 0);
    }
    // A limit that holds one seed set's tape evicts the older one for the newer.
    let one = TruthTape::record(&truth, 9, 50, 200).bytes();
    let cache = TruthCache::with_limit(one + one / 2);
    for seed in [9, 9, 10, 10] {
        run_generic_cached(&truth, &f, &mc.with_seed(seed), Default::default(), &cache);
    }
    assert_eq!(cache.bytes(), one, "one tape held, the newest");
}

/// `f` in a pool of `threads` threads.
fn on_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

#[test]
fn runs_summed_side_by_side_give_the_sums_of_runs_one_after_the_other() {
    // An evaluation of fewer chunks than threads computes a chunk's runs side by side and
    // adds their sums in run order; on one thread they run one after the other. 60 runs
    // are one chunk (side by side from 2 threads on), 130 are three (from 4 on). The
    // walk's runs end early (truth overflow at step 17, and a filter that fails at once),
    // so a stopped run's partial sums take the same path.
    for name in ["ctrv", "ins_gnss"] {
        let (model, mc) = shipped(name);
        let filter = model.filter(&model.truth_values());
        for runs in [60, 130] {
            let mc = mc.with_runs(runs).unwrap().with_steps(80).unwrap();
            let one = on_threads(1, || run_generic(model.truth(), &filter, &mc));
            for threads in [2, 3, 8] {
                let many = on_threads(threads, || run_generic(model.truth(), &filter, &mc));
                assert_same(
                    &one,
                    &many,
                    &format!("{name}, {runs} runs, {threads} threads"),
                );
            }
        }
    }
    let truth = Blowup { stop: 17 };
    for (q, r) in [(1.0, 1.0), (-1.0, 1.0)] {
        let f = walk_filter(q, r);
        let mc = McConfig::new(60, 40).unwrap().with_seed(5);
        let one = on_threads(1, || run_generic(&truth, &f, &mc));
        assert!(one.diverged_runs() > 0);
        let many = on_threads(4, || run_generic(&truth, &f, &mc));
        assert_same(&one, &many, &format!("walk, q = {q}"));
    }
}

#[test]
fn the_cache_counts_what_it_replayed_and_what_it_simulated() {
    // One seed set evaluated four times: the first two simulate (the second tapes), the
    // last two replay. A cache too small for the tape simulates all four and says why.
    use autotune::internals::experiment::TruthReuse;
    let truth = Blowup { stop: usize::MAX };
    let f = walk_filter(1.0, 1.0);
    let mc = McConfig::new(50, 30).unwrap().with_seed(3);
    for (limit, replayed, too_large) in [(TruthCache::DEFAULT_LIMIT, 2, false), (1000, 0, true)] {
        let cache = TruthCache::with_limit(limit);
        let before = cache.usage();
        for _ in 0..4 {
            run_generic_cached(&truth, &f, &mc, Default::default(), &cache);
        }
        let usage = cache.usage();
        assert_eq!(usage.replayed, replayed, "limit {limit}");
        assert_eq!(usage.simulated, 4 - replayed, "limit {limit}");
        assert_eq!(usage.too_large, too_large, "limit {limit}");
        match TruthReuse::taped(&cache, before) {
            TruthReuse::Taped {
                replayed: r,
                simulated: s,
                too_large: t,
                limit: l,
            } => assert_eq!((r, s, t, l), (replayed, 4 - replayed, too_large, limit)),
            other => panic!("{other:?}"),
        }
        // Counted from a later point, only what came after.
        let mid = cache.usage();
        run_generic_cached(&truth, &f, &mc, Default::default(), &cache);
        let TruthReuse::Taped {
            replayed,
            simulated,
            ..
        } = TruthReuse::taped(&cache, mid)
        else {
            unreachable!()
        };
        assert_eq!(replayed + simulated, 1);
    }
}
