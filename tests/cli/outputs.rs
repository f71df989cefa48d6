//! No output replaces an input (issue 37, item 1), listed from the command line's own
//! definition so that a new flag cannot be missed.
//!
//! Every path-valued argument of every `autotune` subcommand is either an output
//! (`autotune::app::OUTPUT_ARGS`) or an input; [`INPUT_ARGS`] names the inputs, and a test
//! fails when the CLI has a path argument in neither list. For every output argument, the
//! table [`cases`] gives at least one runnable invocation; each is run with the output
//! pointed at each of the invocation's inputs — as named, through a hard link, and spelt
//! `sub/../name` — with and without `--force`. Each must exit 2 before any work, with one
//! line naming the flag, and leave every input byte for byte as it was and no temporary
//! file behind.

use std::path::{Path, PathBuf};
use std::process::Command as Process;

use assert_cmd::cargo::CommandCargoExt;
use autotune::app::{Cli, OUTPUT_ARGS};
use clap::CommandFactory;

/// The path-valued arguments that are inputs, by subcommand and argument id.
const INPUT_ARGS: &[(&str, &str)] = &[
    ("check", "problem"),
    ("check", "records"),
    ("check", "measurements"),
    ("check", "config"),
    ("check", "reference"),
    ("tune", "problem"),
    ("tune", "measurements"),
    ("tune", "reference"),
    ("tune", "init_record"),
    ("merge", "shards"),
    ("nis", "logs"),
    ("nis", "follow"),
    ("simulate", "problem"),
    ("estimate", "problem"),
    ("estimate", "measurements"),
];

/// One invocation: its arguments before the output flag (`@P` the problem, `@C` a tuned
/// config, `@R` records, `@M` measurements, `@S0`/`@S1` shard files, `@L` a field log, each
/// an input), the output flag, and inputs the command reads that its arguments do not name.
struct Case {
    sub: &'static str,
    args: &'static [&'static str],
    flag: &'static str,
    hidden: &'static [&'static str],
}

fn cases() -> Vec<Case> {
    let c = |sub, args, flag, hidden| Case {
        sub,
        args,
        flag,
        hidden,
    };
    vec![
        c("check", &["check", "@P", "--config", "@C"], "--junit", &[]),
        c("check", &["check", "@P", "--config", "@C"], "--report", &[]),
        c("check", &["check", "--records", "@R"], "--junit", &[]),
        c(
            "check",
            &["check", "@P", "--measurements", "@M"],
            "--report",
            &[],
        ),
        c(
            "check",
            &["check", "@P", "--shard", "0/2"],
            "--sums-out",
            &[],
        ),
        c("tune", &["tune", "@P"], "--out", &[]),
        c("tune", &["tune", "@P"], "--report", &[]),
        c(
            "tune",
            &["tune", "@P", "--measurements", "@M"],
            "--out",
            &[],
        ),
        c(
            "tune",
            &["tune", "@P", "--init", "ml", "--init-record", "@M"],
            "--out",
            &[],
        ),
        c("merge", &["merge", "@S0", "@S1"], "--junit", &["@P"]),
        c("merge", &["merge", "@S0", "@S1"], "--report", &["@P"]),
        c("nis", &["nis", "@L"], "--junit", &[]),
        c("nis", &["nis", "@L"], "--report", &[]),
        c(
            "nis",
            &["nis", "--follow", "@L", "--for", "5"],
            "--junit",
            &[],
        ),
        c(
            "simulate",
            &["simulate", "@P", "--truth", "x.csv"],
            "--out",
            &[],
        ),
        c(
            "simulate",
            &["simulate", "@P", "--out", "z.csv"],
            "--truth",
            &[],
        ),
        c(
            "estimate",
            &["estimate", "@P", "--measurements", "@M"],
            "--out",
            &[],
        ),
        // init reads no input: its --out has nothing to collide with.
        c("init", &["init", "starter"], "--out", &[]),
    ]
}

/// The inputs, written into a fresh directory: cv1d's problem file and tuned config,
/// records, a simulated measurement record, the two shards of a check and a field log.
struct Inputs {
    dir: tempfile::TempDir,
}

impl Inputs {
    fn new() -> Inputs {
        let dir = tempfile::tempdir().unwrap();
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let d = dir.path();
        std::fs::copy(root.join("problems/cv1d.toml"), d.join("cv1d.toml")).unwrap();
        std::fs::copy(root.join("tuned/cv1d.toml"), d.join("tuned.toml")).unwrap();
        std::fs::copy(
            root.join("examples/records/cv1d.csv"),
            d.join("records.csv"),
        )
        .unwrap();
        std::fs::copy(
            root.join("examples/records/cv1d_innovations.csv"),
            d.join("log.csv"),
        )
        .unwrap();
        let inputs = Inputs { dir };
        let p = inputs.path("@P");
        run(&[
            "simulate",
            p.to_str().unwrap(),
            "--out",
            inputs.path("@M").to_str().unwrap(),
            "--steps",
            "300",
        ])
        .assert_code(0);
        for (i, s) in ["@S0", "@S1"].into_iter().enumerate() {
            run(&[
                "check",
                p.to_str().unwrap(),
                "--runs",
                "128",
                "--steps",
                "20",
                "--shard",
                &format!("{i}/2"),
                "--sums-out",
                inputs.path(s).to_str().unwrap(),
            ])
            .assert_code(0);
        }
        inputs
    }

    fn path(&self, token: &str) -> PathBuf {
        let name = match token {
            "@P" => "cv1d.toml",
            "@C" => "tuned.toml",
            "@R" => "records.csv",
            "@M" => "measured.csv",
            "@S0" => "shard0.json",
            "@S1" => "shard1.json",
            "@L" => "log.csv",
            other => panic!("no input {other}"),
        };
        self.dir.path().join(name)
    }

    /// Every input's bytes.
    fn snapshot(&self) -> Vec<(PathBuf, Vec<u8>)> {
        ["@P", "@C", "@R", "@M", "@S0", "@S1", "@L"]
            .iter()
            .map(|t| (self.path(t), std::fs::read(self.path(t)).unwrap()))
            .collect()
    }
}

struct Ran {
    code: Option<i32>,
    stderr: String,
}

impl Ran {
    fn assert_code(&self, code: i32) {
        assert_eq!(self.code, Some(code), "stderr: {}", self.stderr);
    }
}

fn run(args: &[&str]) -> Ran {
    let out = Process::cargo_bin("autotune")
        .unwrap()
        .args(args)
        .output()
        .unwrap();
    Ran {
        code: out.status.code(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

/// The path-valued arguments of each subcommand, by id.
fn path_args() -> Vec<(String, String)> {
    let cli = Cli::command();
    let mut v = Vec::new();
    for sub in cli.get_subcommands() {
        for arg in sub.get_arguments() {
            if arg.get_value_parser().type_id() == std::any::TypeId::of::<PathBuf>() {
                v.push((sub.get_name().to_string(), arg.get_id().to_string()));
            }
        }
    }
    v
}

#[test]
fn every_path_argument_is_an_output_or_a_listed_input() {
    for (sub, id) in path_args() {
        let output = OUTPUT_ARGS.contains(&id.as_str());
        let input = INPUT_ARGS.contains(&(sub.as_str(), id.as_str()));
        assert!(
            output != input,
            "{sub} {id}: a path argument must be an output (app::OUTPUT_ARGS) or an input (INPUT_ARGS here), and not both"
        );
        if output {
            let flag = format!("--{}", id.replace('_', "-"));
            assert!(
                cases().iter().any(|c| c.sub == sub && c.flag == flag),
                "{sub} {flag}: an output with no case in this file's table"
            );
        }
    }
    // The table names no argument the CLI does not have.
    for (sub, id) in INPUT_ARGS {
        assert!(
            path_args().iter().any(|(s, i)| s == sub && i == id),
            "{sub} {id} is not a path argument of the CLI"
        );
    }
}

#[test]
fn no_output_flag_replaces_an_input() {
    let inputs = Inputs::new();
    let before = inputs.snapshot();
    let mut tried = 0;
    for case in cases() {
        let resolve = |a: &&str| -> String {
            if a.starts_with('@') {
                inputs.path(a).to_str().unwrap().to_string()
            } else if a.ends_with(".csv") && !a.contains('/') {
                // An output beside the inputs that is not the one under test.
                inputs.dir.path().join(a).to_str().unwrap().to_string()
            } else {
                a.to_string()
            }
        };
        let args: Vec<String> = case.args.iter().map(resolve).collect();
        let targets: Vec<&str> = case
            .args
            .iter()
            .chain(case.hidden)
            .copied()
            .filter(|a| a.starts_with('@'))
            .collect();
        for token in targets {
            let input = inputs.path(token);
            for (spelling, target) in spellings(&inputs, &input, case.flag, tried) {
                for force in [false, true] {
                    let mut all = args.clone();
                    all.push(case.flag.to_string());
                    all.push(target.to_str().unwrap().to_string());
                    if force {
                        all.push("--force".into());
                    }
                    let refs: Vec<&str> = all.iter().map(String::as_str).collect();
                    let ran = run(&refs);
                    let what = format!("{} ({spelling}, force {force})", all.join(" "));
                    assert_eq!(ran.code, Some(2), "{what}: {}", ran.stderr);
                    assert_eq!(ran.stderr.lines().count(), 1, "{what}: {}", ran.stderr);
                    assert!(ran.stderr.contains(case.flag), "{what}: {}", ran.stderr);
                    assert!(
                        ran.stderr.contains("is an input of this command"),
                        "{what}: {}",
                        ran.stderr
                    );
                    tried += 1;
                }
            }
        }
        assert_eq!(inputs.snapshot(), before, "{} {}", case.sub, case.flag);
    }
    let leftovers: Vec<String> = walk(inputs.dir.path())
        .into_iter()
        .filter(|n| n.ends_with(".tmp") || n.contains("probe"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    // The cases' 27 (output, input) pairs, three spellings each (one for the 9 of a report
    // directory), with and without --force.
    assert_eq!(tried, 2 * (18 * 3 + 9), "refusals tried");
}

/// A file autotune did not write is replaced only with --force (item 6); one it wrote (it
/// carries the mark) is replaced without; a stale rejected config it did not write stays.
#[test]
fn only_autotunes_own_files_are_replaced_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    std::fs::copy(root.join("problems/cv1d.toml"), d.join("cv1d.toml")).unwrap();
    std::fs::create_dir(d.join("tuned")).unwrap();
    let mine = "my notes, not autotune's\n";
    std::fs::write(d.join("tuned/cv1d.rejected.toml"), mine).unwrap();
    for (flag, name) in [
        ("--junit", "ci.xml"),
        ("--report", "rep"),
        ("--out", "t.toml"),
    ] {
        let target = d.join(name);
        let user_file = if flag == "--report" {
            std::fs::create_dir(&target).unwrap();
            target.join("report.md")
        } else {
            target.clone()
        };
        std::fs::write(&user_file, mine).unwrap();
        let sub = if flag == "--out" { "tune" } else { "check" };
        let args = [
            sub,
            "cv1d.toml",
            "--runs",
            "20",
            "--steps",
            "20",
            flag,
            name,
        ];
        let ran = run_in(d, &args);
        assert_eq!(ran.code, Some(2), "{flag}: {}", ran.stderr);
        assert!(
            ran.stderr.contains("exists without autotune's mark"),
            "{}",
            ran.stderr
        );
        assert!(ran.stderr.contains("--force"), "{}", ran.stderr);
        assert_eq!(std::fs::read_to_string(&user_file).unwrap(), mine);
        // With --force it is replaced, and from then on it carries the mark.
        let mut forced = args.to_vec();
        forced.push("--force");
        let ran = run_in(d, &forced);
        assert_ne!(ran.code, Some(2), "{flag} --force: {}", ran.stderr);
        assert_ne!(std::fs::read_to_string(&user_file).unwrap(), mine);
        let ran = run_in(d, &args);
        assert_ne!(ran.code, Some(2), "{flag} again: {}", ran.stderr);
    }
    // A tune that confirms writes tuned/cv1d.toml and leaves the rejected config it did
    // not write alone.
    let ran = run_in(d, &["tune", "cv1d.toml", "--force"]);
    assert_eq!(ran.code, Some(0), "{}", ran.stderr);
    assert!(d.join("tuned/cv1d.toml").is_file());
    assert_eq!(
        std::fs::read_to_string(d.join("tuned/cv1d.rejected.toml")).unwrap(),
        mine
    );
}

fn run_in(dir: &Path, args: &[&str]) -> Ran {
    let out = Process::cargo_bin("autotune")
        .unwrap()
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap();
    Ran {
        code: out.status.code(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

/// The ways an output can name `input`: as given, through a hard link in another
/// directory, and spelt `sub/../name`; for a report directory, a directory whose
/// `report.json` is a hard link to it (or the input itself, not a directory).
fn spellings(inputs: &Inputs, input: &Path, flag: &str, n: usize) -> Vec<(&'static str, PathBuf)> {
    let d = inputs.dir.path();
    let name = input.file_name().unwrap();
    let other = d.join(format!("other{n}"));
    std::fs::create_dir_all(&other).unwrap();
    if flag == "--report" {
        for f in ["report.json", "report.md", "report.html"] {
            let link = other.join(f);
            if f == "report.json" {
                std::fs::hard_link(input, &link).unwrap();
            } else {
                std::fs::write(&link, "<!-- written by autotune 0 -->").unwrap();
            }
        }
        return vec![("a report directory holding a hard link to it", other)];
    }
    let link = other.join(name);
    std::fs::hard_link(input, &link).unwrap();
    let sub = d.join(format!("sub{n}"));
    std::fs::create_dir_all(&sub).unwrap();
    vec![
        ("as named", input.to_path_buf()),
        ("a hard link", link),
        ("sub/../name", sub.join("..").join(name)),
    ]
}

fn walk(dir: &Path) -> Vec<String> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            v.extend(walk(&e.path()));
        } else {
            v.push(e.file_name().to_string_lossy().into_owned());
        }
    }
    v
}
