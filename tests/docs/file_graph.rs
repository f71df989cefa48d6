//! The layout file by file (issue 40): inside a folder as between the layers, the files of
//! src/ import one another without a circle, so each can be read knowing only the files it
//! names. An import is followed through re-exports (`pub use`) to the file that defines the
//! item: a folder's `mod.rs` that re-exports its children is their facade, not a file they
//! depend on. What a file defines and its children use (a shared type in `mod.rs`) is an
//! arrow back up, and makes a circle with the `mod.rs` that calls them.
//!
//! Also here: the rule "by command" of docs/ARCHITECTURE.md, for every command the command
//! line has: its body in `commands/`, its rendering in `report/<command>/`, and no command's
//! rendering reaching into another's.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// One source file of the library: where it is, the module path it defines and its code
/// (comments, literals and `#[cfg(test)]` items removed).
struct Source {
    rel: String,
    module: Vec<String>,
    code: String,
}

fn sources() -> Vec<Source> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    walk(&src, &mut files);
    let mut out = Vec::new();
    for f in files {
        let rel = f
            .strip_prefix(&src)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        let module = module_path(&rel);
        // The binary is a crate of its own; a `tests` module and its files are tests.
        if rel == "main.rs" || module.iter().any(|m| m == "tests") {
            continue;
        }
        let text = std::fs::read_to_string(&f).unwrap();
        out.push(Source {
            rel,
            module,
            code: without_tests(&strip(&text)),
        });
    }
    out
}

fn walk(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            walk(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// `stats/sums.rs` → `[stats, sums]`, `stats/mod.rs` → `[stats]`, `lib.rs` → `[]`.
fn module_path(rel: &str) -> Vec<String> {
    let mut parts: Vec<String> = rel
        .trim_end_matches(".rs")
        .split('/')
        .map(String::from)
        .collect();
    if parts.last().is_some_and(|p| p == "mod" || p == "lib") {
        parts.pop();
    }
    parts
}

/// The text with comments, string and character literals blanked (a path in a message or a
/// doc comment is not an import).
fn strip(text: &str) -> String {
    let b: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        let next = b.get(i + 1).copied();
        if c == '/' && next == Some('/') {
            while i < b.len() && b[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && next == Some('*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == '/' && b.get(i + 1) == Some(&'*') {
                    depth += 1;
                    i += 2;
                } else if b[i] == '*' && b.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
            out.push(' ');
        } else if c == 'r'
            && (next == Some('"') || next == Some('#'))
            && !b[..i]
                .last()
                .is_some_and(|p| p.is_alphanumeric() || *p == '_')
        {
            // A raw string: r"…", r#"…"#, …
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&'"') {
                out.push(c);
                i += 1;
                continue;
            }
            j += 1;
            loop {
                if j >= b.len() {
                    break;
                }
                if b[j] == '"' && (0..hashes).all(|h| b.get(j + 1 + h) == Some(&'#')) {
                    j += 1 + hashes;
                    break;
                }
                j += 1;
            }
            out.push_str("\"\"");
            i = j;
        } else if c == '"' {
            i += 1;
            while i < b.len() && b[i] != '"' {
                i += if b[i] == '\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else if c == '\'' {
            // A character literal ('x', '\n', '\u{1F600}') or a lifetime ('a).
            if next == Some('\\') {
                let mut j = i + 2;
                while j < b.len() && b[j] != '\'' {
                    j += 1;
                }
                i = j + 1;
                out.push_str("' '");
            } else if b.get(i + 2) == Some(&'\'') {
                i += 3;
                out.push_str("' '");
            } else {
                out.push(c);
                i += 1;
            }
        } else {
            out.push(c);
            i += 1;
        }
    }
    out
}

/// The code without its `#[cfg(test)]` items (a test module may reach anywhere).
fn without_tests(code: &str) -> String {
    let mut out = String::with_capacity(code.len());
    let mut rest = code;
    while let Some(at) = rest.find("#[cfg(test)]") {
        out.push_str(&rest[..at]);
        let item = &rest[at..];
        // The item ends at its first `;` outside braces, or at its closing brace.
        let mut depth = 0usize;
        let mut end = item.len();
        for (k, ch) in item.char_indices() {
            match ch {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        end = k + 1;
                        break;
                    }
                }
                ';' if depth == 0 => {
                    end = k + 1;
                    break;
                }
                _ => {}
            }
        }
        rest = &item[end..];
    }
    out.push_str(rest);
    out
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// Whether `word` starts at byte `at` of `code` as a whole word.
fn word_at(code: &str, at: usize, word: &str) -> bool {
    code[at..].starts_with(word)
        && !code[..at].chars().next_back().is_some_and(is_ident)
        && !code[at + word.len()..].chars().next().is_some_and(is_ident)
}

/// One `use` declaration: whether it re-exports (`pub use`, `pub(crate) use`, …), its
/// paths as written (a group expanded), and where it sits in the code.
struct Use {
    public: bool,
    paths: Vec<Vec<String>>,
    span: std::ops::Range<usize>,
}

fn uses(code: &str) -> Vec<Use> {
    let mut out = Vec::new();
    for (at, _) in code.match_indices("use") {
        if !word_at(code, at, "use") {
            continue;
        }
        let before = code[..at].trim_end();
        // A statement's start: after `;`, a brace, an attribute, a visibility, or the start.
        let public = before.ends_with("pub")
            || before.ends_with(')') && {
                let open = before.rfind('(').unwrap_or(0);
                before[..open].trim_end().ends_with("pub")
            };
        let starts = before.is_empty()
            || public
            || before.ends_with(';')
            || before.ends_with('{')
            || before.ends_with('}')
            || before.ends_with(']');
        if !starts {
            continue;
        }
        let Some(len) = code[at..].find(';') else {
            continue;
        };
        let tree = &code[at + "use".len()..at + len];
        out.push(Use {
            public,
            paths: expand(tree),
            span: at..at + len,
        });
    }
    out
}

/// `a::{b, c::{d, e as f}, g::*}` → `[a, b]`, `[a, c, d]`, `[a, c, e]`, `[a, g, *]`.
fn expand(tree: &str) -> Vec<Vec<String>> {
    let tree = tree.trim().trim_start_matches("::");
    let Some(open) = tree.find('{') else {
        let path = tree.split(" as ").next().unwrap().trim();
        let parts: Vec<String> = path
            .split("::")
            .map(|s| s.trim().to_string())
            .filter(|s| !s.is_empty())
            .collect();
        return if parts.is_empty() {
            vec![]
        } else {
            vec![parts]
        };
    };
    let prefix: Vec<String> = tree[..open]
        .split("::")
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .collect();
    let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
    let mut items = Vec::new();
    let (mut depth, mut start) = (0usize, 0);
    for (k, ch) in inner.char_indices() {
        match ch {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                items.push(&inner[start..k]);
                start = k + 1;
            }
            _ => {}
        }
    }
    items.push(&inner[start..]);
    let mut out = Vec::new();
    for item in items.into_iter().filter(|s| !s.trim().is_empty()) {
        for sub in expand(item) {
            let mut p = prefix.clone();
            p.extend(sub.into_iter().filter(|s| s != "self"));
            out.push(p);
        }
    }
    out
}

/// The names of the modules a file declares (`mod x;`, `pub mod y;`), its children.
fn children(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for (at, _) in code.match_indices("mod ") {
        if !word_at(code, at, "mod") {
            continue;
        }
        let rest = &code[at + 4..];
        let name: String = rest.chars().take_while(|c| is_ident(*c)).collect();
        if !name.is_empty() && rest[name.len()..].trim_start().starts_with(';') {
            out.insert(name);
        }
    }
    out
}

/// A path as written in `me` (`super::x::Y`, `crate::a::B`, `child::f`) made absolute from
/// the crate root; `None` for a path outside the crate (`std::…`, `nalgebra::…`).
fn absolute(me: &[String], path: &[String], kids: &BTreeSet<String>) -> Option<Vec<String>> {
    let head = path.first()?;
    let mut out: Vec<String>;
    let mut rest = path;
    match head.as_str() {
        "crate" => {
            out = vec![];
            rest = &path[1..];
        }
        "self" => {
            out = me.to_vec();
            rest = &path[1..];
        }
        "super" => {
            out = me.to_vec();
            while rest.first().is_some_and(|p| p == "super") {
                out.pop();
                rest = &rest[1..];
            }
        }
        h if kids.contains(h) => out = me.to_vec(),
        _ => return None,
    }
    out.extend(rest.iter().cloned());
    Some(out)
}

/// The paths into the crate a file's code names outside its `use` declarations
/// (`crate::linalg::symmetrize(…)`, `super::Verdict`, `child::run(…)`).
fn inline_paths(
    code: &str,
    skip: &[std::ops::Range<usize>],
    kids: &BTreeSet<String>,
) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let bytes = code.as_bytes();
    let mut i = 0;
    while i < code.len() {
        if skip.iter().any(|r| r.contains(&i)) || !code.is_char_boundary(i) {
            i += 1;
            continue;
        }
        let starts_word = !code[..i].chars().next_back().is_some_and(|c| is_ident(c) || c == ':')
            // `pub(in crate::x)` is a visibility, not an import.
            && !code[..i].trim_end().ends_with("(in");
        if !starts_word || !(bytes[i] as char).is_ascii_alphabetic() {
            i += 1;
            continue;
        }
        let end = i + code[i..]
            .find(|c: char| !is_ident(c))
            .unwrap_or(code.len() - i);
        let head = &code[i..end];
        if !(head == "crate" || head == "super" || head == "self" || kids.contains(head))
            || !code[end..].starts_with("::")
        {
            i = end;
            continue;
        }
        let mut path = vec![head.to_string()];
        let mut j = end;
        while code[j..].starts_with("::") {
            let s = j + 2;
            let e = s + code[s..]
                .find(|c: char| !is_ident(c))
                .unwrap_or(code.len() - s);
            if e == s {
                break;
            }
            path.push(code[s..e].to_string());
            j = e;
        }
        out.push(path);
        i = j;
    }
    out
}

/// What each file imports, followed to the defining files.
struct Graph {
    /// file → (file it imports → one path that shows the arrow)
    edges: BTreeMap<String, BTreeMap<String, String>>,
}

impl Graph {
    fn of(sources: &[Source]) -> Graph {
        let by_module: BTreeMap<Vec<String>, &Source> =
            sources.iter().map(|s| (s.module.clone(), s)).collect();
        // name a file re-exports → the absolute path it re-exports (`*` for a glob)
        let mut reexports: BTreeMap<&str, Vec<(String, Vec<String>)>> = BTreeMap::new();
        let mut imports: BTreeMap<&str, Vec<Vec<String>>> = BTreeMap::new();
        for s in sources {
            let kids = children(&s.code);
            let found = uses(&s.code);
            for u in &found {
                for p in &u.paths {
                    let Some(a) = absolute(&s.module, p, &kids) else {
                        continue;
                    };
                    if u.public {
                        let name = p.last().unwrap().clone();
                        // A re-exported name the file's own code uses is also its import.
                        if name != "*" && uses_name(&s.code, &found, &name) {
                            imports.entry(&s.rel).or_default().push(a.clone());
                        }
                        reexports.entry(&s.rel).or_default().push((name, a));
                    } else {
                        imports.entry(&s.rel).or_default().push(a);
                    }
                }
            }
            let spans: Vec<_> = found.iter().map(|u| u.span.clone()).collect();
            for p in inline_paths(&s.code, &spans, &kids) {
                if let Some(a) = absolute(&s.module, &p, &kids) {
                    imports.entry(&s.rel).or_default().push(a);
                }
            }
        }
        let resolve = |path: &[String]| -> Option<String> {
            let mut path = path.to_vec();
            for _ in 0..32 {
                let (file, rest) = (0..=path.len())
                    .rev()
                    .find_map(|k| by_module.get(&path[..k]).map(|f| (*f, path[k..].to_vec())))?;
                let Some(item) = rest.first() else {
                    return Some(file.rel.clone());
                };
                let re = reexports.get(file.rel.as_str());
                let named = re.and_then(|r| r.iter().find(|(n, _)| n == item));
                match named {
                    Some((_, target)) => {
                        let mut next = target.clone();
                        next.extend(rest[1..].iter().cloned());
                        path = next;
                    }
                    None => {
                        // Through a glob re-export when the file does not define the item.
                        let glob = re.and_then(|r| r.iter().find(|(n, _)| n == "*"));
                        match glob {
                            Some((_, target)) if !defines(&file.code, item) => {
                                let mut next = target[..target.len() - 1].to_vec();
                                next.extend(rest.iter().cloned());
                                path = next;
                            }
                            _ => return Some(file.rel.clone()),
                        }
                    }
                }
            }
            None
        };
        let mut edges: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
        for s in sources {
            let mine = edges.entry(s.rel.clone()).or_default();
            for a in imports.get(s.rel.as_str()).into_iter().flatten() {
                if let Some(f) = resolve(a)
                    && f != s.rel
                {
                    mine.entry(f)
                        .or_insert_with(|| format!("crate::{}", a.join("::")));
                }
            }
        }
        Graph { edges }
    }

    /// The strongly connected components of more than one file (Tarjan's algorithm).
    fn circles(&self) -> Vec<Vec<String>> {
        struct State<'a> {
            g: &'a Graph,
            index: BTreeMap<&'a str, usize>,
            low: BTreeMap<&'a str, usize>,
            stack: Vec<&'a str>,
            on: BTreeSet<&'a str>,
            out: Vec<Vec<String>>,
        }
        fn visit<'a>(st: &mut State<'a>, v: &'a str) {
            let n = st.index.len();
            st.index.insert(v, n);
            st.low.insert(v, n);
            st.stack.push(v);
            st.on.insert(v);
            for w in st.g.edges.get(v).into_iter().flat_map(|e| e.keys()) {
                if !st.index.contains_key(w.as_str()) {
                    visit(st, w);
                    let lw = st.low[w.as_str()];
                    let lv = st.low.get_mut(v).unwrap();
                    *lv = (*lv).min(lw);
                } else if st.on.contains(w.as_str()) {
                    let iw = st.index[w.as_str()];
                    let lv = st.low.get_mut(v).unwrap();
                    *lv = (*lv).min(iw);
                }
            }
            if st.low[v] == st.index[v] {
                let mut comp = Vec::new();
                while let Some(w) = st.stack.pop() {
                    st.on.remove(w);
                    comp.push(w.to_string());
                    if w == v {
                        break;
                    }
                }
                if comp.len() > 1 {
                    comp.sort();
                    st.out.push(comp);
                }
            }
        }
        let mut st = State {
            g: self,
            index: BTreeMap::new(),
            low: BTreeMap::new(),
            stack: Vec::new(),
            on: BTreeSet::new(),
            out: Vec::new(),
        };
        for v in self.edges.keys() {
            if !st.index.contains_key(v.as_str()) {
                visit(&mut st, v);
            }
        }
        st.out
    }
}

/// Whether `name` occurs as a word in `code` outside its `use` declarations.
fn uses_name(code: &str, decls: &[Use], name: &str) -> bool {
    code.match_indices(name)
        .any(|(at, _)| word_at(code, at, name) && !decls.iter().any(|u| u.span.contains(&at)))
}

/// Whether a file's code defines `item` itself (a function, type, constant, module, macro).
fn defines(code: &str, item: &str) -> bool {
    [
        "fn", "struct", "enum", "trait", "type", "const", "static", "mod", "union",
    ]
    .iter()
    .any(|kw| {
        code.match_indices(item).any(|(at, _)| {
            word_at(code, at, item) && code[..at].trim_end().ends_with(kw) && {
                let before = code[..at].trim_end();
                word_at(before, before.len() - kw.len(), kw)
            }
        })
    }) || code.contains(&format!("macro_rules! {item}"))
}

#[test]
fn no_file_of_src_imports_in_a_circle_even_inside_a_folder() {
    let graph = Graph::of(&sources());
    let circles = graph.circles();
    let mut report = String::new();
    for c in &circles {
        report.push_str(&format!("a circle of {} files:\n", c.len()));
        for a in c {
            for (b, why) in &graph.edges[a] {
                if c.contains(b) {
                    report.push_str(&format!("  {a} -> {b}  ({why})\n"));
                }
            }
        }
    }
    assert!(circles.is_empty(), "{report}");
}

#[test]
fn the_file_graph_follows_reexports_and_sees_every_kind_of_path() {
    let files = [
        ("lib.rs", "mod a;\nmod b;\npub use a::Thing;\n"),
        // a's facade re-exports its child; the child uses b through the crate root's re-export.
        (
            "a/mod.rs",
            "mod inner;\npub use inner::Thing;\npub(crate) use inner::*;\n",
        ),
        (
            "a/inner.rs",
            "pub struct Thing;\nfn f() { crate::b::g(); }\n",
        ),
        // b calls its child by name and uses a's item through a's facade, in a grouped import;
        // a comment, a string and a test module name more, which are not imports.
        (
            "b/mod.rs",
            "mod leaf;\nuse crate::{a::{Thing}};\n// crate::a::inner::x\n\
             pub fn g() { let s = \"crate::a\"; leaf::h(); }\n#[cfg(test)]\nmod tests { use super::*; }\n",
        ),
        ("b/leaf.rs", "pub fn h() { super::super::a::Thing; }\n"),
    ];
    let sources: Vec<Source> = files
        .iter()
        .map(|(rel, text)| Source {
            rel: rel.to_string(),
            module: module_path(rel),
            code: without_tests(&strip(text)),
        })
        .collect();
    let g = Graph::of(&sources);
    let arrows: BTreeSet<(String, String)> = g
        .edges
        .iter()
        .flat_map(|(a, to)| to.keys().map(move |b| (a.clone(), b.clone())))
        .collect();
    let want: BTreeSet<(String, String)> = [
        ("a/inner.rs", "b/mod.rs"),
        ("b/mod.rs", "a/inner.rs"),
        ("b/mod.rs", "b/leaf.rs"),
        ("b/leaf.rs", "a/inner.rs"),
    ]
    .iter()
    .map(|(a, b)| (a.to_string(), b.to_string()))
    .collect();
    assert_eq!(arrows, want);
    let circle = ["a/inner.rs", "b/leaf.rs", "b/mod.rs"]
        .map(String::from)
        .to_vec();
    assert_eq!(g.circles(), vec![circle]);
}

/// The file's command folder under `src/report/` (`report/check/html.rs` → `check`).
fn report_folder(rel: &str) -> Option<&str> {
    let rest = rel.strip_prefix("report/")?;
    let (folder, _) = rest.split_once('/')?;
    Some(folder)
}

#[test]
fn every_command_has_its_body_in_commands_and_renders_in_its_own_report_folder() {
    use clap::CommandFactory;
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    // `completions` prints the command line's own completion scripts: it is the command
    // line's, not a command of the library (app/completions.rs).
    let commands: Vec<String> = autotune::app::Cli::command()
        .get_subcommands()
        .map(|c| c.get_name().to_string())
        .filter(|n| n != "completions")
        .collect();
    assert!(commands.len() >= 7, "{commands:?}");
    let sources = sources();
    let mut violations = Vec::new();
    for c in &commands {
        // The body: a library function named after the command in commands/ (`merge`, a
        // check over shards, is `commands::check::merge`).
        let body = format!("pub fn {c}(");
        if !sources
            .iter()
            .any(|s| s.rel.starts_with("commands/") && s.code.contains(&body))
        {
            violations.push(format!("`{c}`: no `{body}…` in src/commands/"));
        }
    }
    for c in ["check", "tune", "nis", "estimate", "init"] {
        let folder = src.join("report").join(c);
        if !folder.is_dir() && !src.join("report").join(format!("{c}.rs")).is_file() {
            violations.push(format!("`{c}` renders, but has no src/report/{c}/"));
        }
    }
    let graph = Graph::of(&sources);
    for (a, to) in &graph.edges {
        let Some(mine) = report_folder(a) else {
            continue;
        };
        for (b, why) in to {
            if let Some(theirs) = report_folder(b)
                && theirs != mine
                && commands.iter().any(|c| c == mine)
                && commands.iter().any(|c| c == theirs)
            {
                violations.push(format!(
                    "{a} (`{mine}`'s rendering) uses {b} (`{theirs}`'s): {why}; what both need belongs in src/report/"
                ));
            }
        }
    }
    assert!(violations.is_empty(), "{}", violations.join("\n"));
}
