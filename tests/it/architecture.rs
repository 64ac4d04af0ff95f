//! docs/architecture.md kept true: its floors against the imports of the
//! code. Every top-level module of `src/` stands on one floor of the
//! page's table, every import (`crate::…`, `super::…`, through a folder's
//! re-exports) runs to a lower floor, and inside each folder no files
//! import each other in a circle. The code's tests (`#[cfg(test)]` to the
//! end of a file) may reach anywhere and are not read.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A module's path below `crate`, e.g. ["sampler", "moves", "curved"].
type ModPath = Vec<String>;

struct Source {
    module: ModPath,
    /// Whether the file is a folder's `mod.rs` (its module is the folder).
    is_folder: bool,
    text: String,
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn sources() -> Vec<Source> {
    fn walk(dir: &Path, prefix: &[String], out: &mut Vec<Source>) {
        let mut entries: Vec<_> =
            std::fs::read_dir(dir).unwrap().flatten().map(|e| e.path()).collect();
        entries.sort();
        for path in entries {
            let name = path.file_name().unwrap().to_str().unwrap().to_string();
            if path.is_dir() {
                let mut p = prefix.to_vec();
                p.push(name);
                walk(&path, &p, out);
            } else if let Some(stem) = name.strip_suffix(".rs") {
                if prefix.is_empty() && (stem == "lib" || stem == "main") {
                    continue;
                }
                let is_folder = stem == "mod";
                let mut module = prefix.to_vec();
                if !is_folder {
                    module.push(stem.to_string());
                }
                let text = std::fs::read_to_string(&path).unwrap();
                // the code's tests are not part of the floors, nor are comments
                let code = match text.find("#[cfg(test)]") {
                    Some(i) => &text[..i],
                    None => &text,
                };
                let text: String = code
                    .lines()
                    .filter(|l| !l.trim_start().starts_with("//"))
                    .map(|l| format!("{l}\n"))
                    .collect();
                out.push(Source { module, is_folder, text });
            }
        }
    }
    let mut out = Vec::new();
    walk(&root().join("src"), &[], &mut out);
    out
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// The identifier at the start of `s`.
fn ident(s: &str) -> &str {
    &s[..s.find(|c: char| !is_ident(c)).unwrap_or(s.len())]
}

/// Every path the text names from `crate::` or `super::`, as the segments
/// after it (a `{…}` group gives one path per first segment in it), with
/// how many `super`s it climbs (None for `crate::`).
fn references(text: &str) -> Vec<(Option<usize>, Vec<String>)> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find(['c', 's']) {
        let (before, at) = rest.split_at(i);
        let preceded = before.chars().last().is_some_and(|c| is_ident(c) || c == ':');
        let start = if at.starts_with("crate::") && !preceded {
            Some((None, "crate::".len()))
        } else if at.starts_with("super::") && !preceded {
            let mut n = 0;
            let mut k = 0;
            while at[k..].starts_with("super::") {
                n += 1;
                k += "super::".len();
            }
            Some((Some(n), k))
        } else {
            None
        };
        let Some((climb, k)) = start else {
            rest = &at[1..];
            continue;
        };
        let mut tail = &at[k..];
        let mut segments = Vec::new();
        loop {
            let id = ident(tail);
            if id.is_empty() {
                break;
            }
            segments.push(id.to_string());
            tail = &tail[id.len()..];
            if let Some(t) = tail.strip_prefix("::") {
                tail = t;
            } else {
                break;
            }
        }
        if tail.starts_with('{') {
            let close = tail.find('}').unwrap_or(tail.len());
            for item in tail[1..close].split(',') {
                let id = ident(item.trim());
                if !id.is_empty() {
                    let mut s = segments.clone();
                    s.push(id.to_string());
                    out.push((climb, s));
                }
            }
        } else if !segments.is_empty() {
            out.push((climb, segments));
        }
        rest = &at[k..];
    }
    out
}

/// For each folder, the module its `mod.rs` re-exports each name from
/// (`pub use child::Name;`, `pub use child::{A, B};`).
fn reexports(sources: &[Source]) -> BTreeMap<ModPath, BTreeMap<String, String>> {
    let mut out = BTreeMap::new();
    for s in sources.iter().filter(|s| s.is_folder) {
        let mut map = BTreeMap::new();
        for line in s.text.lines() {
            let Some(body) = line.trim().strip_prefix("pub use ") else { continue };
            let child = ident(body).to_string();
            let after = &body[child.len()..];
            let Some(after) = after.strip_prefix("::") else { continue };
            let names: Vec<&str> = match after.strip_prefix('{') {
                Some(group) => group.trim_end_matches(['}', ';']).split(',').collect(),
                None => vec![after.trim_end_matches(';')],
            };
            for n in names {
                let n = n.trim();
                let name = n.rsplit("::").next().unwrap_or(n);
                let name = name.split(" as ").last().unwrap().trim();
                if !name.is_empty() {
                    map.insert(name.to_string(), child.clone());
                }
            }
        }
        out.insert(s.module.clone(), map);
    }
    out
}

/// The module a path leads to, as deep as the modules go: `crate::a::B`
/// is `a`'s child that re-exports B where `a` re-exports it, else `a`.
fn resolve(
    path: &[String],
    modules: &BTreeSet<ModPath>,
    reexports: &BTreeMap<ModPath, BTreeMap<String, String>>,
) -> ModPath {
    let mut at: ModPath = Vec::new();
    for seg in path {
        let mut next = at.clone();
        next.push(seg.clone());
        if modules.contains(&next) {
            at = next;
            continue;
        }
        if let Some(child) = reexports.get(&at).and_then(|m| m.get(seg)) {
            let mut next = at.clone();
            next.push(child.clone());
            if modules.contains(&next) {
                at = next;
            }
        }
        break;
    }
    at
}

/// Every import as (from, to) module paths.
fn imports(sources: &[Source]) -> Vec<(ModPath, ModPath)> {
    let mut modules: BTreeSet<ModPath> = BTreeSet::new();
    for s in sources {
        for k in 1..=s.module.len() {
            modules.insert(s.module[..k].to_vec());
        }
    }
    let reexports = reexports(sources);
    let mut out = Vec::new();
    for s in sources {
        for (climb, segments) in references(&s.text) {
            // `super` is the module above this file's (for a `mod.rs`, above its folder)
            let absolute: Vec<String> = match climb {
                None => segments,
                Some(n) => s.module[..s.module.len().saturating_sub(n)]
                    .iter()
                    .cloned()
                    .chain(segments)
                    .collect(),
            };
            let target = resolve(&absolute, &modules, &reexports);
            if !target.is_empty() {
                out.push((s.module.clone(), target));
            }
        }
    }
    out
}

/// The floors of docs/architecture.md's table: module name → floor.
fn floors() -> BTreeMap<String, usize> {
    let page = std::fs::read_to_string(root().join("docs/architecture.md")).unwrap();
    let mut out = BTreeMap::new();
    for line in page.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells.len() < 4 {
            continue;
        }
        let Ok(floor) = cells[1].parse::<usize>() else { continue };
        for name in cells[2].split(',') {
            let name = name.trim().trim_matches('`');
            assert!(out.insert(name.to_string(), floor).is_none(), "{name} on two floors");
        }
    }
    out
}

/// Where `a` and `b` part: the folder they share and the entry of it each
/// stands in (the two differ), if neither contains the other.
fn parting(a: &ModPath, b: &ModPath) -> Option<(ModPath, String, String)> {
    let common = a.iter().zip(b).take_while(|(x, y)| x == y).count();
    (common < a.len() && common < b.len())
        .then(|| (a[..common].to_vec(), a[common].clone(), b[common].clone()))
}

#[test]
fn every_import_runs_to_a_lower_floor_of_the_architecture_page() {
    let sources = sources();
    let floors = floors();
    let top: BTreeSet<String> = sources.iter().map(|s| s.module[0].clone()).collect();
    let listed: BTreeSet<String> = floors.keys().cloned().collect();
    assert_eq!(top, listed, "the page's floors list every module of src/ once, and no other");
    let mut climbs = BTreeSet::new();
    for (from, to) in imports(&sources) {
        let (a, b) = (&from[0], &to[0]);
        if a != b && floors[a] <= floors[b] {
            climbs.insert(format!(
                "{} (floor {}) imports {} (floor {})",
                from.join("::"),
                floors[a],
                to.join("::"),
                floors[b]
            ));
        }
    }
    assert!(climbs.is_empty(), "imports that do not run down a floor:\n{}", lines(&climbs));
}

#[test]
fn no_modules_import_each_other_in_a_circle_in_any_folder() {
    let sources = sources();
    // each folder's graph: its entries (files and sub-folders) and who imports whom
    let mut graphs: BTreeMap<ModPath, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for (from, to) in imports(&sources) {
        if let Some((folder, a, b)) = parting(&from, &to) {
            graphs.entry(folder).or_default().entry(a).or_default().insert(b);
        }
    }
    let mut circles = BTreeSet::new();
    for (folder, graph) in &graphs {
        for start in graph.keys() {
            // a path back to `start`
            let mut stack = vec![(start.clone(), vec![start.clone()])];
            let mut seen = BTreeSet::new();
            while let Some((node, trail)) = stack.pop() {
                for next in graph.get(&node).into_iter().flatten() {
                    if next == start {
                        let mut ring = trail.clone();
                        let first = ring.iter().min().unwrap().clone();
                        let at = ring.iter().position(|n| *n == first).unwrap();
                        ring.rotate_left(at);
                        circles.insert(format!(
                            "in src/{}: {}",
                            folder.join("/"),
                            ring.join(" -> ")
                        ));
                    } else if seen.insert(next.clone()) {
                        let mut t = trail.clone();
                        t.push(next.clone());
                        stack.push((next.clone(), t));
                    }
                }
            }
        }
    }
    assert!(circles.is_empty(), "modules that import each other:\n{}", lines(&circles));
}

/// The reader itself, on a file it must read right: a group, a re-export
/// and `super` from a folder's file and from a `mod.rs`.
#[test]
fn the_reader_finds_what_a_file_imports() {
    let refs = references("use crate::model::{Params, LANES};\nlet x = super::super::testing::run(); use super::{a, b::C};");
    assert_eq!(
        refs,
        vec![
            (None, vec!["model".into(), "Params".into()]),
            (None, vec!["model".into(), "LANES".into()]),
            (Some(2), vec!["testing".into(), "run".into()]),
            (Some(1), vec!["a".into()]),
            (Some(1), vec!["b".into()]),
        ]
    );
    let sources = vec![
        Source { module: vec!["p".into()], is_folder: true, text: "pub use q::Thing;\n".into() },
        Source { module: vec!["p".into(), "q".into()], is_folder: false, text: String::new() },
        Source {
            module: vec!["p".into(), "r".into()],
            is_folder: false,
            text: "use super::Thing; use crate::s::x;".into(),
        },
        Source { module: vec!["s".into()], is_folder: true, text: "use super::p::Thing;".into() },
    ];
    let found = imports(&sources);
    let v = |s: &[&str]| s.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    assert!(found.contains(&(v(&["p", "r"]), v(&["p", "q"]))), "{found:?}");
    assert!(found.contains(&(v(&["p", "r"]), v(&["s"]))), "{found:?}");
    assert!(found.contains(&(v(&["s"]), v(&["p", "q"]))), "{found:?}");
}

fn lines(set: &BTreeSet<String>) -> String {
    set.iter().map(|s| format!("  {s}")).collect::<Vec<_>>().join("\n")
}
