//! The layout docs/ARCHITECTURE.md draws is the layout of the code: every module of src/ has
//! a layer in its table, and every `crate::` path in a module's code names a module of a
//! lower layer (so there are no circles and no import climbs back). Comments and
//! `#[cfg(test)] mod tests` blocks are not code dependencies and are skipped.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// `module → layer` from the table in docs/ARCHITECTURE.md (rows `| 3 | `montecarlo` | …`).
fn layers() -> BTreeMap<String, u32> {
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/ARCHITECTURE.md"))
        .unwrap();
    let mut out = BTreeMap::new();
    for line in doc.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells.len() >= 4
            && let Ok(layer) = cells[1].parse::<u32>()
        {
            let module = cells[2].trim_matches('`').to_string();
            assert!(
                out.insert(module.clone(), layer).is_none(),
                "{module} twice"
            );
        }
    }
    assert!(out.len() >= 10, "the layer table was not found: {out:?}");
    out
}

/// Every `.rs` file under `dir`, into `out`.
pub(crate) fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let p = entry.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The top-level module a source file belongs to (`None` for lib.rs and main.rs).
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).unwrap();
    let first = rel.components().next()?.as_os_str().to_string_lossy();
    let name = first.trim_end_matches(".rs").to_string();
    (name != "lib" && name != "main").then_some(name)
}

/// The code of a file without comment lines and without its unit-test module.
fn code(text: &str) -> String {
    let text = text.split("#[cfg(test)]\nmod tests").next().unwrap();
    text.lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The top-level modules a piece of code names through `crate::m` or `crate::{m, …}`.
fn named_modules(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let ident = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect()
    };
    for (i, _) in code.match_indices("crate::") {
        let rest = &code[i + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            let end = group.find('}').unwrap_or(group.len());
            for item in group[..end].split(',') {
                let name = ident(item.trim());
                if name.starts_with(|c: char| c.is_ascii_lowercase()) {
                    out.insert(name);
                }
            }
        } else {
            let name = ident(rest);
            // An item of the crate root (`crate::SimRng`): the root re-exports every layer,
            // so naming it climbs to the top; the test reports it.
            if name.starts_with(|c: char| c.is_ascii_uppercase()) {
                out.insert(format!("{ROOT}{name}"));
            } else if name.starts_with(|c: char| c.is_ascii_lowercase()) {
                out.insert(name);
            }
        }
    }
    out
}

/// How [`named_modules`] marks an item of the crate root.
const ROOT: &str = "root:";

#[test]
fn every_import_goes_to_a_lower_layer_of_the_documented_table() {
    let layers = layers();
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut seen = BTreeSet::new();
    let mut violations = Vec::new();
    for f in &files {
        let Some(me) = module_of(&src, f) else {
            continue;
        };
        seen.insert(me.clone());
        let Some(&mine) = layers.get(&me) else {
            violations.push(format!("{me}: not in docs/ARCHITECTURE.md's table"));
            continue;
        };
        let text = std::fs::read_to_string(f).unwrap();
        for other in named_modules(&code(&text)) {
            if other == me {
                continue;
            }
            if let Some(item) = other.strip_prefix(ROOT) {
                violations.push(format!(
                    "{} names the crate root's {item}: import it from its module (the root re-exports every layer)",
                    f.strip_prefix(&src).unwrap().display()
                ));
                continue;
            }
            match layers.get(&other) {
                Some(&theirs) if theirs < mine => {}
                Some(&theirs) => violations.push(format!(
                    "{} (layer {mine}) uses {other} (layer {theirs})",
                    f.strip_prefix(&src).unwrap().display()
                )),
                None => violations.push(format!("{me} uses {other}, which the table lacks")),
            }
        }
    }
    for m in layers.keys() {
        if !seen.contains(m) {
            violations.push(format!("{m}: in the table but not in src/"));
        }
    }
    assert!(violations.is_empty(), "{}", violations.join("\n"));
}

#[test]
fn the_scanner_sees_plain_and_grouped_paths_and_skips_comments_and_tests() {
    let text = "use crate::stats::Accumulator;\nuse crate::{filter::Filter, model};\n\
                // crate::app in a comment\nfn f() { crate::linalg::symmetrize(m); }\n\
                let r: crate::SimRng;\n#[cfg(test)]\nmod tests {\n use crate::report;\n}\n";
    let got = named_modules(&code(text));
    let want: BTreeSet<String> = ["filter", "linalg", "model", "root:SimRng", "stats"]
        .into_iter()
        .map(String::from)
        .collect();
    assert_eq!(got, want);
}

/// The names a `pub use` (or `pub type`) at the top level of `text` makes public, outside
/// the `internals` module.
fn reexported_names(text: &str) -> BTreeSet<String> {
    let code = code(text);
    let mut names = BTreeSet::new();
    let mut rest = code.as_str();
    while let Some(at) = rest.find("pub use ") {
        let tail = &rest[at + "pub use ".len()..];
        let end = tail.find(';').expect("a `pub use` ends with `;`");
        let item = &tail[..end];
        let list = match item.find('{') {
            Some(open) => &item[open + 1..item.rfind('}').unwrap()],
            None => item.rsplit("::").next().unwrap(),
        };
        for name in list.split(',').map(str::trim).filter(|n| !n.is_empty()) {
            let name = name.rsplit(" as ").next().unwrap();
            if name != "*" {
                names.insert(name.to_string());
            }
        }
        rest = &tail[end..];
    }
    for line in code.lines() {
        if let Some(t) = line.trim().strip_prefix("pub type ") {
            names.insert(
                t.split(|c: char| !c.is_alphanumeric() && c != '_')
                    .next()
                    .unwrap()
                    .to_string(),
            );
        }
    }
    names
}

/// The backticked names in the rows of docs/ARCHITECTURE.md's "Public API" table whose first
/// cell starts with `row`, notes in parentheses aside.
fn documented_names(row: &str) -> BTreeSet<String> {
    let doc = std::fs::read_to_string("docs/ARCHITECTURE.md").unwrap();
    let table = doc
        .split("## Public API")
        .nth(1)
        .expect("docs/ARCHITECTURE.md has a Public API section");
    let table = table.split("\n## ").next().unwrap();
    let mut names = BTreeSet::new();
    for line in table.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells.len() < 3 || !cells[1].starts_with(row) {
            continue;
        }
        let mut what = String::new();
        let mut depth = 0;
        for c in cells[2].chars() {
            match c {
                '(' => depth += 1,
                ')' => depth -= 1,
                _ if depth == 0 => what.push(c),
                _ => {}
            }
        }
        names.extend(
            what.split('`')
                .skip(1)
                .step_by(2)
                .filter(|n| n.chars().all(|c| c.is_alphanumeric() || c == '_'))
                .map(str::to_string),
        );
    }
    names
}

#[test]
fn the_documented_public_api_is_the_crate_roots_and_the_preludes() {
    let lib = std::fs::read_to_string("src/lib.rs").unwrap();
    // The internals module re-exports every private module for the crate's own tests; it
    // is not the public API (hidden from the documentation).
    let (public, internals) = lib.split_once("pub mod internals {").unwrap();
    let after_internals = &internals[internals.find("\n}\n").unwrap()..];
    let root = reexported_names(&format!("{public}{after_internals}"));
    let documented = documented_names("crate root");
    assert_eq!(
        root.difference(&documented).collect::<Vec<_>>(),
        Vec::<&String>::new(),
        "exported at the crate root (src/lib.rs) but missing from docs/ARCHITECTURE.md's Public API table"
    );
    assert_eq!(
        documented.difference(&root).collect::<Vec<_>>(),
        Vec::<&String>::new(),
        "in docs/ARCHITECTURE.md's Public API table but not exported at the crate root"
    );
    let prelude = reexported_names(&std::fs::read_to_string("src/prelude.rs").unwrap());
    let mut documented = documented_names("`prelude`");
    documented.remove("prelude");
    assert_eq!(
        prelude, documented,
        "the prelude and its row in docs/ARCHITECTURE.md"
    );
    // Nothing else is public at the top: the modules the table names and `internals`.
    let modules: BTreeSet<&str> = public
        .lines()
        .chain(after_internals.lines())
        .filter_map(|l| l.strip_prefix("pub mod "))
        .map(|m| m.trim_end_matches(';'))
        .collect();
    assert_eq!(
        modules,
        BTreeSet::from(["app", "cluster", "commands", "prelude", "report"]),
        "public modules of src/lib.rs"
    );
    let doc = std::fs::read_to_string("docs/ARCHITECTURE.md").unwrap();
    for m in &modules {
        assert!(
            doc.contains(&format!("\n| `{m}` |")),
            "the public module {m} has no row in docs/ARCHITECTURE.md's Public API table"
        );
    }
}
