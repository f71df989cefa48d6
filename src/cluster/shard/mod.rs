//! Shard files: one share of a check's chunk sums, written by `autotune check --shard i/n
//! --sums-out FILE` and merged by `autotune merge` (format: docs/src/cluster.md).
//!
//! A shard file is one JSON document: the format and its version, the settings that make
//! its sums (the problem's name, path and SHA-256, the parameter values and the Monte Carlo
//! settings, each number with its IEEE bits), which share it is, and each of its chunks'
//! sums in autotune's sums format (base64, the format a worker's sums answer uses). Shards
//! merge only when every setting is the same, every share of the count is there once and
//! every chunk once: the merged sums are then the one-process sums, bit for bit.

mod format;
mod merge;

pub use format::{
    CheckSetup, FORMAT, MAX_FILE, MergeProblem, MergeRefusal, Number, Setup, SetupRefusal,
    ShardChunk, ShardFile, ShardHead, ShardIndex, ShardSettings, VERSION,
};
pub use merge::{merge_stream, plan, read_head};

#[cfg(test)]
mod tests {
    use std::path::{Path, PathBuf};

    use super::format::*;
    use super::merge::*;
    use crate::montecarlo::CHUNK;
    use crate::montecarlo::Share;
    use crate::stats::Accumulator;

    /// A check of 130 runs (three chunks: 64, 64 and 2 runs) of 3 steps, 2 states, 1
    /// measurement component and 1 lag.
    fn settings() -> ShardSettings {
        ShardSettings {
            problem: "p".into(),
            file: PathBuf::from("p.toml"),
            sha256: "00".into(),
            params: vec![("q".into(), Number::of(0.5))],
            runs: 2 * CHUNK + 2,
            steps: 3,
            seed: 7,
            alpha: Number::of(0.05),
            lags: 1,
            gate: "full".into(),
            engine: "auto".into(),
            nis_only: false,
            n_x: 2,
            n_z: 1,
        }
    }

    fn head(name: &str, index: usize, count: usize, settings: &ShardSettings) -> ShardHead {
        ShardHead {
            path: PathBuf::from(name),
            settings: settings.clone(),
            shard: ShardIndex { index, count },
        }
    }

    fn refused(heads: &[ShardHead]) -> String {
        plan(heads).unwrap_err().to_string()
    }

    #[test]
    fn plan_orders_the_shares_and_names_the_file_at_fault() {
        let s = settings();
        let heads = [
            head("c", 2, 3, &s),
            head("a", 0, 3, &s),
            head("b", 1, 3, &s),
        ];
        let order: Vec<_> = plan(&heads).unwrap().iter().map(|h| &h.path).collect();
        assert_eq!(order, [Path::new("a"), Path::new("b"), Path::new("c")]);

        assert_eq!(refused(&[]), "autotune merge: no shard files");
        let mut other = s.clone();
        other.steps = 4;
        assert_eq!(
            refused(&[head("a", 0, 2, &s), head("b", 1, 2, &other)]),
            "b: its steps differs from a's: shards of different problems or settings do not merge"
        );
        assert_eq!(
            refused(&[head("a", 0, 2, &s), head("b", 1, 3, &s)]),
            "b: shard 1/3 cannot merge with a's shards of 2"
        );
        assert_eq!(
            refused(&[head("a", 0, 2, &s), head("b", 2, 2, &s)]),
            "b: shard 2/2 is not a shard of 2"
        );
        assert_eq!(
            refused(&[head("a", 0, 2, &s), head("b", 0, 2, &s)]),
            "b: shard 0/2 is also a"
        );
        assert_eq!(
            refused(&[head("a", 0, 3, &s), head("b", 2, 3, &s)]),
            "a: shard 1/3 is missing: give every shard's file"
        );
    }

    #[test]
    fn every_setting_that_differs_is_named() {
        type Change = fn(&mut ShardSettings);
        let changes: [(&str, Change); 14] = [
            ("problem", |s| s.problem.push('x')),
            ("file", |s| s.file.push("x")),
            ("sha256 (the problem file's digest)", |s| s.sha256.push('1')),
            ("params", |s| s.params[0].1 = Number::of(0.25)),
            ("runs", |s| s.runs += 1),
            ("steps", |s| s.steps += 1),
            ("seed", |s| s.seed += 1),
            ("alpha", |s| s.alpha = Number::of(0.01)),
            ("lags", |s| s.lags += 1),
            ("gate", |s| s.gate = "mean".into()),
            ("engine", |s| s.engine = "generic".into()),
            ("nis_only", |s| s.nis_only = true),
            ("n_x", |s| s.n_x += 1),
            ("n_z", |s| s.n_z += 1),
        ];
        let s = settings();
        assert_eq!(first_difference(&s, &s.clone()), None);
        for (field, change) in changes {
            let mut o = s.clone();
            change(&mut o);
            assert_eq!(first_difference(&s, &o), Some(field));
        }
    }

    #[test]
    fn a_shards_settings_are_checked_against_the_problem_they_name() {
        use crate::experiment::Experiment;
        // Mock: one parameter p0, states s0 and s1, one measurement component.
        let problem = crate::tune::tests::Mock::new(&[1.0], &[&[1.0], &[1.0]]);
        let mut s = settings();
        s.params = vec![("p0".into(), Number::of(0.5))];
        let setup = s.setup(&problem).unwrap();
        assert_eq!(setup.theta, [0.5]);
        assert_eq!(
            (setup.mc.runs(), setup.mc.steps(), setup.mc.seed()),
            (2 * CHUNK + 2, 3, 7)
        );
        assert_eq!(problem.state_names().len(), 2);
        let refused = |f: &dyn Fn(&mut ShardSettings)| {
            let mut t = s.clone();
            f(&mut t);
            t.setup(&problem).unwrap_err()
        };
        assert_eq!(
            refused(&|t| t.n_x = 3),
            SetupRefusal::Dimension {
                field: "n_x",
                declared: 3,
                actual: 2
            }
        );
        assert_eq!(
            refused(&|t| t.n_z = 2),
            SetupRefusal::Dimension {
                field: "n_z",
                declared: 2,
                actual: 1
            }
        );
        assert_eq!(
            refused(&|t| t.params[0].0 = "q".into()),
            SetupRefusal::Parameters {
                problem: vec!["p0".into()]
            }
        );
        assert_eq!(
            refused(&|t| t.params[0].1 = Number::of(f64::INFINITY)),
            SetupRefusal::NotFinite("p0".into())
        );
        assert_eq!(
            refused(&|t| t.gate = "most".into()),
            SetupRefusal::Invalid("gate")
        );
        assert_eq!(
            refused(&|t| t.engine = "fast".into()),
            SetupRefusal::Invalid("engine")
        );
        assert!(matches!(
            refused(&|t| t.runs = 0),
            SetupRefusal::Settings(_)
        ));
        assert_eq!(
            refused(&|t| t.n_x = 3).to_string(),
            "its settings' n_x is 3, but the problem's sums have 2"
        );
    }

    #[test]
    fn a_number_keeps_its_bits() {
        for x in [0.1, -0.0, f64::MIN_POSITIVE / 3.0, 1e308, f64::NAN] {
            assert_eq!(Number::of(x).get().map(f64::to_bits), Some(x.to_bits()));
        }
        let bad = Number {
            value: 1.into(),
            bits: "not hex".into(),
        };
        assert_eq!(bad.get(), None);
    }

    /// Chunk `c`'s sums with values that differ by chunk, step and component.
    fn chunk_sums(s: &ShardSettings, c: usize) -> Accumulator {
        let mut a = s.shape().empty();
        a.runs = (s.runs - c * CHUNK).min(CHUNK);
        for k in 0..s.steps {
            a.nees_sum[k] = (c * 7 + k) as f64 / 3.0;
            a.nis_sum[k] = 1.0 / (1.0 + (c * 5 + k) as f64);
        }
        a.state_comp_total[1] = c as f64 + 0.1;
        a
    }

    #[test]
    fn shard_files_merge_into_the_one_process_sums_bit_for_bit() {
        let s = settings();
        let chunks = s.runs.div_ceil(CHUNK);
        let dir = tempfile::tempdir().unwrap();
        let mut heads = Vec::new();
        for i in 0..2 {
            let share = Share::new(i, 2).unwrap();
            let parts: Vec<(usize, Accumulator)> = share
                .chunks(chunks)
                .map(|c| (c, chunk_sums(&s, c)))
                .collect();
            let path = dir.path().join(format!("shard{i}.json"));
            std::fs::write(&path, ShardFile::new(s.clone(), share, &parts).to_json()).unwrap();
            heads.push(read_head(&path).unwrap());
        }
        heads.reverse();
        let merged = merge_stream(&plan(&heads).unwrap(), &s).unwrap();
        let parts = (0..chunks).map(|c| (c, chunk_sums(&s, c))).collect();
        let one = Share::merge(s.runs, s.shape().empty(), parts).unwrap();
        // Debug prints each float's shortest exact form: equal text, equal bits.
        assert_eq!(format!("{merged:?}"), format!("{one:?}"));
        assert_eq!(merged.runs, s.runs);
    }

    #[test]
    fn a_chunk_decodes_only_into_its_own_shape() {
        let s = settings().shape();
        let sums = chunk_sums(&settings(), 2);
        let bytes = s.encode(2, &sums);
        let back = s.decode(2, &bytes).unwrap();
        assert_eq!(format!("{back:?}"), format!("{sums:?}"));
        // Chunk 0 holds 64 runs, chunk 2 only 2: its bytes are not chunk 0's.
        assert!(s.decode(0, &bytes).is_err());
        assert!(s.decode(2, &bytes[..bytes.len() - 1]).is_err());
    }
}
