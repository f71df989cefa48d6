//! Bad input of every kind, through the real binary: `autotune check` exits 2 with exactly one
//! line on stderr that names the file (or the command-line option) and the field, and never
//! panics.
//!
//! Each row of the table below takes `problems/cv1d.toml`, breaks it with exact textual edits
//! (every edit must find its text, so a row cannot silently test a valid file), writes it to a
//! temporary directory and runs `autotune check` on it, possibly with options or a tuned
//! config. A positive control runs the same plumbing on the unmodified file.

use std::path::{Path, PathBuf};

use assert_cmd::Command;

const CV1D: &str = include_str!("../../problems/cv1d.toml");
const CTRV: &str = include_str!("../../problems/ctrv.toml");
const ORBIT2D: &str = include_str!("../../problems/orbit2d.toml");
const INS_GNSS: &str = include_str!("../../problems/ins_gnss.toml");

/// The problem file a row runs on.
enum Problem {
    /// cv1d.toml with these `(find, replace)` edits, each applied to the first match.
    Edit(&'static [(&'static str, &'static str)]),
    /// cv1d.toml with this text appended.
    Append(&'static str),
    /// These exact bytes.
    Bytes(&'static [u8]),
    /// A catalog problem's text, parsed and changed by the function (which must find
    /// everything it changes), then written back.
    Catalog(&'static str, fn(&mut toml::Table)),
    /// A path where no file exists.
    Missing,
    /// A directory instead of a file.
    Directory,
}

/// The tuned config passed with `--config`, if any.
enum Config {
    None,
    /// A file with this text.
    Text(&'static str),
    /// A path where no file exists.
    Missing,
}

/// Which file the error must name.
#[derive(Clone, Copy, PartialEq)]
enum Source {
    ProblemFile,
    ConfigFile,
    /// A command-line option (the expected strings name it, e.g. `--alpha`).
    CommandLine,
}

enum Expect {
    /// Exit 2; one line on stderr naming the source, then containing every string
    /// (the first is the field).
    Error(Source, &'static [&'static str]),
    /// Valid input: exit 0 (consistent) or 1 (inconsistent), never 2.
    Runs,
}

struct Row {
    name: &'static str,
    problem: Problem,
    config: Config,
    args: &'static [&'static str],
    expect: Expect,
}

/// cv1d.toml broken by `edits`; the error must name the problem file and `names`.
fn edit(
    name: &'static str,
    edits: &'static [(&'static str, &'static str)],
    names: &'static [&'static str],
) -> Row {
    file(name, Problem::Edit(edits), names)
}

/// A problem file made by `problem`; the error must name it and `names`.
fn file(name: &'static str, problem: Problem, names: &'static [&'static str]) -> Row {
    Row {
        name,
        problem,
        config: Config::None,
        args: &[],
        expect: Expect::Error(Source::ProblemFile, names),
    }
}

/// Unmodified cv1d.toml with bad options `args`; the error must contain `names`.
fn option(
    name: &'static str,
    args: &'static [&'static str],
    names: &'static [&'static str],
) -> Row {
    Row {
        name,
        problem: Problem::Edit(&[]),
        config: Config::None,
        args,
        expect: Expect::Error(Source::CommandLine, names),
    }
}

/// Unmodified cv1d.toml with a bad `--config`; the error must name the config file and `names`.
fn config(name: &'static str, config: Config, names: &'static [&'static str]) -> Row {
    Row {
        name,
        problem: Problem::Edit(&[]),
        config,
        args: &[],
        expect: Expect::Error(Source::ConfigFile, names),
    }
}

/// A catalog problem changed by `change`; the error must name it and `names`.
fn catalog(
    name: &'static str,
    base: &'static str,
    change: fn(&mut toml::Table),
    names: &'static [&'static str],
) -> Row {
    file(name, Problem::Catalog(base, change), names)
}

/// The table at `path` (dotted keys) of a parsed problem file.
fn table<'a>(t: &'a mut toml::Table, path: &str) -> &'a mut toml::Table {
    path.split('.').fold(t, |t, k| {
        t.get_mut(k)
            .and_then(toml::Value::as_table_mut)
            .unwrap_or_else(|| panic!("no table {k}"))
    })
}

/// Remove `key` from the table at `path`, which must have it.
fn remove(t: &mut toml::Table, path: &str, key: &str) {
    assert!(table(t, path).remove(key).is_some(), "no {path}.{key}");
}

/// Set `key` in the table at `path`, which must have it already.
fn set(t: &mut toml::Table, path: &str, key: &str, v: toml::Value) {
    let old = table(t, path).insert(key.into(), v);
    assert!(old.is_some(), "no {path}.{key}");
}

fn catalog_rows() -> Vec<Row> {
    vec![
        catalog(
            "unknown model name lists the known ones",
            CTRV,
            |t| set(t, "model", "name", "ctrv_lidar".into()),
            &[
                "model.name",
                "ctrv_lidar",
                "ctrv_radar_lidar",
                "orbit2d",
                "ins_gnss",
            ],
        ),
        catalog(
            "model without a name",
            CTRV,
            |t| remove(t, "model", "name"),
            &["model.name", "missing", "ctrv_radar_lidar"],
        ),
        catalog(
            "model name not a string",
            CTRV,
            |t| set(t, "model", "name", 3.into()),
            &["model.name", "string"],
        ),
        catalog(
            "missing catalog parameter names itself",
            CTRV,
            |t| remove(t, "params", "q_yaw_accel"),
            &["params.q_yaw_accel", "missing", "ctrv_radar_lidar"],
        ),
        catalog(
            "parameter the model does not have",
            CTRV,
            |t| {
                let p = table(t, "params").get("q_accel").unwrap().clone();
                table(t, "params").insert("q_jerk".into(), p);
            },
            &["params.q_jerk", "not a parameter", "q_accel", "q_yaw_accel"],
        ),
        catalog(
            "model and truth both given",
            CTRV,
            |t| {
                let cv1d: toml::Table = toml::from_str(CV1D).unwrap();
                t.insert("truth".into(), cv1d["truth"].clone());
                t.insert("filter".into(), cv1d["filter"].clone());
            },
            &["truth", "[model]", "not both"],
        ),
        catalog(
            "catalog model given state names",
            CTRV,
            |t| {
                t.insert("state_names".into(), vec!["a", "b", "c", "d", "e"].into());
            },
            &["state_names", "ctrv_radar_lidar"],
        ),
        catalog(
            "ctrv truth noise missing",
            CTRV,
            |t| remove(t, "model.truth", "q_yaw_accel"),
            &["model.truth", "q_yaw_accel"],
        ),
        catalog(
            "ctrv truth noise negative",
            CTRV,
            |t| set(t, "model.truth", "q_accel", (-0.5).into()),
            &["model.truth.q_accel"],
        ),
        catalog(
            "ctrv misspelt model setting",
            CTRV,
            |t| {
                table(t, "model").insert("substep".into(), 10.into());
            },
            &["model", "substep"],
        ),
        catalog(
            "orbit2d misspelt truth setting",
            ORBIT2D,
            |t| {
                table(t, "model.truth").insert("q_radiall".into(), 1e-12.into());
            },
            &["model.truth", "q_radiall"],
        ),
        catalog(
            "orbit2d missing parameter",
            ORBIT2D,
            |t| remove(t, "params", "q_along"),
            &["params.q_along", "missing", "orbit2d"],
        ),
        catalog(
            "ins_gnss misspelt truth setting",
            INS_GNSS,
            |t| {
                table(t, "model.truth").insert("q_acel_x".into(), 1e-3.into());
            },
            &["model.truth", "q_acel_x"],
        ),
        catalog(
            "ins_gnss missing parameter",
            INS_GNSS,
            |t| remove(t, "params", "q_accel_z"),
            &["params.q_accel_z", "missing", "ins_gnss"],
        ),
        Row {
            name: "catalog control: ctrv rewritten unchanged runs",
            problem: Problem::Catalog(CTRV, |_| {}),
            config: Config::None,
            args: &[],
            expect: Expect::Runs,
        },
    ]
}

fn rows() -> Vec<Row> {
    let mut rows = linear_rows();
    rows.extend(catalog_rows());
    rows
}

fn linear_rows() -> Vec<Row> {
    vec![
        // --- Dimensions.
        edit(
            "H has 3 columns for 2 states",
            &[("H = [[1.0, 0.0]]", "H = [[1.0, 0.0, 0.0]]")],
            &["truth.H"],
        ),
        edit(
            "H has no rows",
            &[("H = [[1.0, 0.0]]", "H = []")],
            &["truth.H"],
        ),
        edit(
            "x0 has 3 entries",
            &[("x0 = [0.0, 1.0]", "x0 = [0.0, 1.0, 0.0]")],
            &["truth.x0"],
        ),
        edit(
            "P0 is 1x1",
            &[("P0 = [[4.0, 0.0],\n      [0.0, 1.0]]", "P0 = [[4.0]]")],
            &["truth.P0"],
        ),
        edit(
            "filter H has 2 rows for 1 measurement",
            &[("[filter]\n", "[filter]\nH = [[1.0, 0.0], [0.0, 1.0]]\n")],
            &["filter.H"],
        ),
        edit(
            "filter x0 has 1 entry",
            &[("[filter]\n", "[filter]\nx0 = [0.0]\n")],
            &["filter.x0"],
        ),
        // --- filter.map: a filter with other states than the truth (issue 11, item 13).
        edit(
            "map has 3 columns for 2 truth states",
            &[(
                "[filter]\n",
                "[filter]\nmap = [[1.0, 0.0, 0.0]]\nF = [[1.0]]\nH = [[1.0]]\n",
            )],
            &["filter.map", "3 columns", "one per truth state"],
        ),
        edit(
            "map rows of different lengths",
            &[("[filter]\n", "[filter]\nmap = [[1.0, 0.0], [1.0]]\n")],
            &["filter.map"],
        ),
        edit(
            "map with no rows",
            &[("[filter]\n", "[filter]\nmap = []\n")],
            &["filter.map"],
        ),
        edit(
            "map entry not finite",
            &[(
                "[filter]\n",
                "[filter]\nmap = [[1.0, nan]]\nF = [[1.0]]\nH = [[1.0]]\n",
            )],
            &["filter.map"],
        ),
        edit(
            "map without the filter's own F",
            &[("[filter]\n", "[filter]\nmap = [[1.0, 0.0]]\nH = [[1.0]]\n")],
            &["filter.F", "the filter has 1 state ", "filter.map", "own F"],
        ),
        edit(
            "map without the filter's own H",
            &[("[filter]\n", "[filter]\nmap = [[1.0, 0.0]]\nF = [[1.0]]\n")],
            &["filter.H", "filter.map", "own H"],
        ),
        edit(
            "filter F of another size without a map",
            &[("[filter]\n", "[filter]\nF = [[1.0]]\n")],
            &["filter.F", "filter.map"],
        ),
        edit(
            "filter H of another width with a map",
            &[(
                "[filter]\n",
                "[filter]\nmap = [[1.0, 0.0]]\nF = [[1.0]]\nH = [[1.0, 0.0]]\n",
            )],
            &["filter.H"],
        ),
        edit(
            "filter Q index beyond the mapped state",
            &[
                (
                    "[filter]\n",
                    "[filter]\nmap = [[1.0, 0.0]]\nF = [[1.0]]\nH = [[1.0]]\n",
                ),
                (
                    r#"{ kind = "dwna", indices = [0, 1], param = "q_accel" }"#,
                    r#"{ kind = "diag", indices = [1], param = "q_accel" }"#,
                ),
            ],
            &["filter.Q[0].indices", "out of range 0..1"],
        ),
        edit(
            "state_names name the truth's states, not the filter's",
            &[
                (
                    "[filter]\n",
                    "[filter]\nmap = [[1.0, 0.0]]\nF = [[1.0]]\nH = [[1.0]]\n",
                ),
                (
                    r#"{ kind = "dwna", indices = [0, 1], param = "q_accel" }"#,
                    r#"{ kind = "diag", indices = [0], param = "q_accel" }"#,
                ),
            ],
            &["state_names", "filter's states"],
        ),
        edit(
            "map makes the default filter P0 singular",
            &[(
                "[filter]\n",
                "[filter]\nmap = [[1.0, 0.0], [1.0, 0.0]]\nF = [[1.0, 0.0], [0.0, 1.0]]\nH = [[1.0, 0.0]]\n",
            )],
            &["truth.P0 through filter.map"],
        ),
        edit(
            "state_names has 1 name for 2 states",
            &[(
                r#"state_names = ["pos", "vel"]"#,
                r#"state_names = ["pos"]"#,
            )],
            &["state_names"],
        ),
        edit(
            "R index out of range",
            &[("indices = [0], value = 1.0", "indices = [1], value = 1.0")],
            &["truth.R[0].indices"],
        ),
        edit(
            "dwna term with one index",
            &[(
                r#"indices = [0, 1], param = "q_accel""#,
                r#"indices = [0], param = "q_accel""#,
            )],
            &["filter.Q[0].indices"],
        ),
        // --- Covariances.
        edit(
            "P0 asymmetric",
            &[("P0 = [[4.0, 0.0],", "P0 = [[4.0, 0.5],")],
            &["truth.P0"],
        ),
        edit(
            "P0 indefinite (eigenvalues -1, 3)",
            &[(
                "P0 = [[4.0, 0.0],\n      [0.0, 1.0]]",
                "P0 = [[1.0, 2.0],\n      [2.0, 1.0]]",
            )],
            &["truth.P0"],
        ),
        edit(
            "P0 singular, used by the filter",
            &[("[0.0, 1.0]]\nQ =", "[0.0, 0.0]]\nQ =")],
            &["truth.P0 (used as filter.P0)"],
        ),
        edit(
            "P0 singular with huge entries",
            &[(
                "P0 = [[4.0, 0.0],\n      [0.0, 1.0]]",
                "P0 = [[1e308, 1e308],\n      [1e308, 1e308]]",
            )],
            &["truth.P0 (used as filter.P0)"],
        ),
        edit(
            "filter P0 singular",
            &[("[filter]\n", "[filter]\nP0 = [[1.0, 1.0], [1.0, 1.0]]\n")],
            &["filter.P0"],
        ),
        edit(
            "matrix term asymmetric",
            &[(
                r#"Q = [{ kind = "dwna", indices = [0, 1], value = 0.5 }]"#,
                r#"Q = [{ kind = "matrix", matrix = [[1.0, 0.5], [0.0, 1.0]], value = 0.5 }]"#,
            )],
            &["truth.Q[0].matrix"],
        ),
        edit(
            "truth R terms overflow to inf",
            &[(
                r#"R = [{ kind = "diag", indices = [0], value = 1.0 }]"#,
                r#"R = [{ kind = "diag", indices = [0], value = 1e308 }, { kind = "diag", indices = [0], value = 1e308 }]"#,
            )],
            &["truth.R"],
        ),
        edit(
            "dt so large the dwna block overflows",
            &[("dt = 1.0", "dt = 1e100")],
            &["truth.Q[0]"],
        ),
        // --- Non-finite numbers.
        edit(
            "NaN in F",
            &[("F = [[1.0, 1.0],", "F = [[1.0, nan],")],
            &["truth.F[0][1]"],
        ),
        edit(
            "inf in x0",
            &[("x0 = [0.0, 1.0]", "x0 = [0.0, inf]")],
            &["truth.x0[1]"],
        ),
        edit(
            "NaN term value",
            &[("value = 0.5 }", "value = nan }")],
            &["truth.Q[0].value"],
        ),
        edit("NaN dt", &[("dt = 1.0", "dt = nan")], &["dt"]),
        edit("dt zero", &[("dt = 1.0", "dt = 0.0")], &["dt"]),
        // --- Monte Carlo settings.
        edit(
            "alpha = 1.5",
            &[("alpha = 0.05", "alpha = 1.5")],
            &["montecarlo.alpha"],
        ),
        edit(
            "alpha = 0",
            &[("alpha = 0.05", "alpha = 0.0")],
            &["montecarlo.alpha"],
        ),
        edit(
            "runs = 0",
            &[("runs = 200", "runs = 0")],
            &["montecarlo.runs"],
        ),
        edit(
            "runs negative",
            &[("runs = 200", "runs = -5")],
            &["montecarlo.runs"],
        ),
        edit(
            "runs a string",
            &[("runs = 200", r#"runs = "many""#)],
            &["montecarlo.runs"],
        ),
        edit(
            "steps = 0",
            &[("steps = 100", "steps = 0")],
            &["montecarlo.steps"],
        ),
        edit(
            "seed negative",
            &[("seed = 2", "seed = -2")],
            &["montecarlo.seed"],
        ),
        edit(
            "lags negative",
            &[("seed = 2", "seed = 2\nlags = -1")],
            &["montecarlo.lags"],
        ),
        edit(
            "lags far beyond steps",
            &[("seed = 2", "seed = 2\nlags = 5000000000")],
            &["montecarlo.lags"],
        ),
        // --- Schema.
        edit(
            "unknown top-level field",
            &[("dt = 1.0\n", "dt = 1.0\ncolour = \"red\"\n")],
            &["colour"],
        ),
        edit(
            "unknown field in [montecarlo]",
            &[("seed = 2", "seed = 2\nthreads = 4")],
            &["montecarlo.threads"],
        ),
        edit(
            "unknown field in a Q term",
            &[(
                r#"param = "q_accel" }"#,
                r#"param = "q_accel", scale = 2.0 }"#,
            )],
            &["filter.Q[0].scale"],
        ),
        edit(
            "unknown field in a parameter",
            &[("unit = \"m²\"\n", "unit = \"m²\"\nunits = \"m\"\n")],
            &["params.r_pos.units"],
        ),
        edit("dt missing", &[("dt = 1.0\n", "")], &["dt"]),
        edit(
            "truth H missing",
            &[("H = [[1.0, 0.0]]\n", "")],
            &["truth", "H"],
        ),
        edit(
            "unknown term kind",
            &[(
                r#"kind = "dwna", indices = [0, 1], value"#,
                r#"kind = "dwnb", indices = [0, 1], value"#,
            )],
            &["truth.Q[0].kind"],
        ),
        edit(
            "both F and A",
            &[(
                "H = [[1.0, 0.0]]",
                "A = [[0.0, 1.0], [0.0, 0.0]]\nH = [[1.0, 0.0]]",
            )],
            &["truth.A"],
        ),
        edit(
            "neither F nor A",
            &[("F = [[1.0, 1.0],\n     [0.0, 1.0]]\n", "")],
            &["truth.F"],
        ),
        edit(
            "dwna term in R",
            &[(
                r#"kind = "diag", indices = [0], param"#,
                r#"kind = "dwna", indices = [0], param"#,
            )],
            &["filter.R[0].kind"],
        ),
        edit(
            "continuous term without A",
            &[(
                r#"{ kind = "dwna", indices = [0, 1], value = 0.5 }"#,
                r#"{ kind = "continuous", input = [0.0, 1.0], value = 0.5 }"#,
            )],
            &["truth.Q[0].kind"],
        ),
        edit(
            "empty filter Q",
            &[(
                r#"Q = [{ kind = "dwna", indices = [0, 1], param = "q_accel" }]"#,
                "Q = []",
            )],
            &["filter.Q"],
        ),
        edit(
            "term with both param and value",
            &[(r#"param = "r_pos" }"#, r#"param = "r_pos", value = 1.0 }"#)],
            &["filter.R[0].value"],
        ),
        edit(
            "truth term with a param",
            &[(
                "indices = [0], value = 1.0 }",
                r#"indices = [0], param = "r_pos" }"#,
            )],
            &["truth.R[0].param"],
        ),
        edit(
            "negative fixed value in truth",
            &[("value = 0.5 }", "value = -0.5 }")],
            &["truth.Q[0].value"],
        ),
        // --- Parameters.
        edit(
            "term references an unknown parameter",
            &[(r#"param = "q_accel" }"#, r#"param = "q_acel" }"#)],
            &["filter.Q[0].param", "q_acel"],
        ),
        file(
            "parameter defined but unused",
            Problem::Append("\n[params.q_extra]\nvalue = 1.0\n"),
            &["params.q_extra"],
        ),
        edit(
            "lower bound above upper bound",
            &[("value = 0.1\n", "value = 0.1\nlower = 10.0\nupper = 1.0\n")],
            &["params.q_accel.lower"],
        ),
        edit(
            "value below lower bound",
            &[("value = 0.1\n", "value = 0.1\nlower = 1.0\n")],
            &["params.q_accel.value"],
        ),
        edit(
            "parameter value zero",
            &[("value = 0.1\n", "value = 0.0\n")],
            &["params.q_accel.value"],
        ),
        edit(
            "parameter name with a dash",
            &[("[params.q_accel]", "[params.\"q-accel\"]")],
            &["params.q-accel"],
        ),
        file(
            "parameter defined twice",
            Problem::Append("\n[params.r_pos]\nvalue = 1.0\n"),
            &["malformed TOML"],
        ),
        // --- Unreadable files.
        file("missing file", Problem::Missing, &["cannot read"]),
        file("directory", Problem::Directory, &["cannot read"]),
        file("empty file", Problem::Bytes(b""), &["montecarlo"]),
        file(
            "no dt",
            Problem::Bytes(
                b"[montecarlo]\nruns = 10\nsteps = 10\n[model]\nname = \"ctrv_radar_lidar\"\n",
            ),
            &["dt", "missing"],
        ),
        file(
            "not UTF-8",
            Problem::Bytes(b"dt = 1.0 # \xff\n"),
            &["not UTF-8"],
        ),
        edit(
            "malformed TOML (= =)",
            &[("dt = 1.0", "dt = = 1.0")],
            &["malformed TOML"],
        ),
        edit(
            "malformed TOML (unclosed array)",
            &[("x0 = [0.0, 1.0]", "x0 = [0.0, 1.0")],
            &["malformed TOML"],
        ),
        // --- Command-line options.
        option("--alpha 1.5", &["--alpha", "1.5"], &["--alpha"]),
        option("--alpha NaN", &["--alpha", "NaN"], &["--alpha"]),
        option("--runs 0", &["--runs", "0"], &["--runs"]),
        option("--steps 0", &["--steps", "0"], &["--steps"]),
        option(
            "--set unknown parameter",
            &["--set", "q_bogus=1"],
            &["--set", "q_bogus"],
        ),
        option(
            "--set without =",
            &["--set", "q_accel"],
            &["--set", "q_accel"],
        ),
        option(
            "--set negative value",
            &["--set", "q_accel=-1"],
            &["--set", "q_accel"],
        ),
        option("--set inf", &["--set", "r_pos=inf"], &["--set", "r_pos"]),
        // --- Tuned configs (--config).
        config(
            "config names an unknown parameter",
            Config::Text(
                "problem = \"cv1d\"\n[params]\nq_accel = 0.5\nr_pos = 1.0\nq_bogus = 1.0\n",
            ),
            &["params.q_bogus"],
        ),
        config(
            "config lacks a parameter",
            Config::Text("problem = \"cv1d\"\n[params]\nq_accel = 0.5\n"),
            &["params.r_pos"],
        ),
        config(
            "config value negative",
            Config::Text("problem = \"cv1d\"\n[params]\nq_accel = -0.5\nr_pos = 1.0\n"),
            &["params.q_accel"],
        ),
        config(
            "config unknown field",
            Config::Text("problem = \"cv1d\"\nsteps = 3\n[params]\nq_accel = 0.5\nr_pos = 1.0\n"),
            &["steps"],
        ),
        config(
            "config malformed",
            Config::Text("problem = \"cv1d\"\n[params\n"),
            &["malformed TOML"],
        ),
        config("config missing", Config::Missing, &["cannot read"]),
        config(
            "config tuned for a name with a newline",
            Config::Text("problem = \"\\n\"\n[params]\nq_accel = 0.5\nr_pos = 1.0\n"),
            &["problem", "tuned for '\\n'"],
        ),
        // --- Positive control: the same plumbing on the unmodified file is not an input error.
        Row {
            name: "control: unmodified cv1d at the truth's values",
            problem: Problem::Edit(&[]),
            config: Config::None,
            args: &["--set", "q_accel=0.5", "--set", "r_pos=1"],
            expect: Expect::Runs,
        },
    ]
}

/// Write the row's problem file (and config) into `dir`; return their paths.
fn materialize(row: &Row, dir: &Path) -> (PathBuf, Option<PathBuf>) {
    let problem = match &row.problem {
        Problem::Edit(edits) => {
            let mut text = CV1D.to_string();
            for (from, to) in *edits {
                assert_ne!(from, to, "row '{}': edit does nothing", row.name);
                assert!(
                    text.contains(from),
                    "row '{}': cv1d.toml has no {from:?}",
                    row.name
                );
                text = text.replacen(from, to, 1);
            }
            let path = dir.join("problem.toml");
            std::fs::write(&path, text).unwrap();
            path
        }
        Problem::Append(extra) => {
            let path = dir.join("problem.toml");
            std::fs::write(&path, format!("{CV1D}{extra}")).unwrap();
            path
        }
        Problem::Bytes(b) => {
            let path = dir.join("problem.toml");
            std::fs::write(&path, b).unwrap();
            path
        }
        Problem::Catalog(base, change) => {
            let mut t: toml::Table = toml::from_str(base).unwrap();
            change(&mut t);
            let path = dir.join("problem.toml");
            std::fs::write(&path, toml::to_string(&t).unwrap()).unwrap();
            path
        }
        Problem::Missing => dir.join("no-such-problem.toml"),
        Problem::Directory => {
            let path = dir.join("a-directory.toml");
            std::fs::create_dir(&path).unwrap();
            path
        }
    };
    let config = match &row.config {
        Config::None => None,
        Config::Text(t) => {
            let path = dir.join("tuned.toml");
            std::fs::write(&path, t).unwrap();
            Some(path)
        }
        Config::Missing => Some(dir.join("no-such-tuned.toml")),
    };
    (problem, config)
}

/// Run one row; `Err` says what went wrong.
fn run_row(row: &Row) -> Result<(), String> {
    let dir = tempfile::tempdir().unwrap();
    let (problem, config) = materialize(row, dir.path());
    let mut cmd = Command::cargo_bin("autotune").unwrap();
    cmd.arg("check").arg(&problem);
    if let Some(c) = &config {
        cmd.arg("--config").arg(c);
    }
    cmd.args(row.args).arg("--quiet");
    let out = cmd.output().unwrap();
    let code = out.status.code();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let fail = |why: String| {
        Err(format!(
            "{why}\n    exit code: {code:?}\n    stderr: {stderr:?}\n    stdout: {stdout:?}"
        ))
    };
    if stderr.contains("panicked") {
        return fail("panicked".into());
    }
    let (source, names) = match &row.expect {
        Expect::Runs => {
            return match code {
                Some(0 | 1) if stderr.is_empty() => Ok(()),
                _ => fail("valid input should exit 0 or 1 with nothing on stderr".into()),
            };
        }
        Expect::Error(source, names) => (*source, *names),
    };
    if code != Some(2) {
        return fail("exit code should be 2".into());
    }
    if !stdout.is_empty() {
        return fail("nothing should be printed on stdout".into());
    }
    let line = stderr.strip_suffix('\n').unwrap_or(&stderr);
    if line.trim().is_empty() || line.contains('\n') || line.contains('\r') {
        return fail("stderr should be exactly one non-empty line".into());
    }
    // After the file's name comes the field and the message.
    let rest = match source {
        Source::ProblemFile | Source::ConfigFile => {
            let file = if source == Source::ProblemFile {
                problem
            } else {
                config.unwrap()
            };
            let prefix = format!("error: {}", file.display());
            match line.strip_prefix(&prefix) {
                Some(rest) => rest,
                None => return fail(format!("stderr should start with {prefix:?}")),
            }
        }
        Source::CommandLine => match line.strip_prefix("error: ") {
            Some(rest) => rest,
            None => return fail("stderr should start with \"error: \"".into()),
        },
    };
    for name in names {
        if !rest.contains(name) {
            return fail(format!("the message should mention {name:?}"));
        }
    }
    // Shown with --nocapture, to read the messages.
    println!("{:<45} {rest}", row.name);
    Ok(())
}

#[test]
fn every_bad_input_is_one_line_naming_file_and_field_with_exit_2() {
    let rows = rows();
    let mut names = std::collections::HashSet::new();
    for row in &rows {
        assert!(names.insert(row.name), "duplicate row name '{}'", row.name);
    }
    let failures: Vec<String> = rows
        .iter()
        .filter_map(|row| {
            run_row(row)
                .err()
                .map(|e| format!("row '{}': {e}", row.name))
        })
        .collect();
    assert!(
        failures.is_empty(),
        "{} of {} rows failed:\n{}",
        failures.len(),
        rows.len(),
        failures.join("\n")
    );
}
