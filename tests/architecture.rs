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

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
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
            // `crate::SimRng` is the root's, below every layer.
            if name.starts_with(|c: char| c.is_ascii_lowercase()) {
                out.insert(name);
            }
        }
    }
    out
}

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
    let want: BTreeSet<String> = ["filter", "linalg", "model", "stats"]
        .into_iter()
        .map(String::from)
        .collect();
    assert_eq!(got, want);
}
