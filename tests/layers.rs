//! Dependencies run one way (docs/src/architecture.md): each layer imports only the layers below it,
//! and no module imports one that imports it back. Read from the source text: `crate::` and
//! `super::` paths in code (comments and test modules left out).

mod common;
use common::rust_files;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// What each top-level module may import.
const ALLOWED: [(&str, &[&str]); 9] = [
    ("core", &[]),
    ("hw", &["core"]),
    ("logs", &["core"]),
    ("config", &["core"]),
    ("console", &["core"]),
    ("gcs", &["core", "config"]),
    ("sim", &["core", "config", "hw"]),
    ("tasks", &["core", "hw", "logs", "config", "gcs"]),
    (
        "app",
        &[
            "core", "hw", "logs", "config", "console", "gcs", "sim", "tasks",
        ],
    ),
];

/// The module path of a file under `src` (`core/flight/mod.rs` → `core::flight`).
fn module_of(src: &Path, file: &Path) -> String {
    let rel = file.strip_prefix(src).unwrap().with_extension("");
    let mut parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into()).collect();
    if parts.last().is_some_and(|l| l == "mod" || l == "lib") {
        parts.pop();
    }
    parts.join("::")
}

/// The code of a file: comments and the test module left out.
fn code(text: &str) -> String {
    let text = text.split("#[cfg(test)]").next().unwrap_or("");
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The paths following `prefix` in `code`, e.g. `core::flight::Outputs` after `crate::`.
fn paths_after<'a>(code: &'a str, prefix: &str) -> Vec<&'a str> {
    code.match_indices(prefix)
        .filter(|(i, _)| {
            !code[..*i]
                .chars()
                .last()
                .is_some_and(|c| c.is_alphanumeric() || c == '_')
        })
        .map(|(i, _)| {
            let rest = &code[i + prefix.len()..];
            let end = rest
                .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                .unwrap_or(rest.len());
            rest[..end].trim_end_matches(':')
        })
        .collect()
}

/// The longest module in `modules` that `path` names.
fn owner(path: &str, modules: &BTreeSet<String>) -> Option<String> {
    let parts: Vec<&str> = path.split("::").collect();
    (1..=parts.len())
        .rev()
        .map(|k| parts[..k].join("::"))
        .find(|m| modules.contains(m))
}

fn imports() -> BTreeMap<String, BTreeSet<String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.retain(|f| !f.ends_with("main.rs"));
    let modules: BTreeSet<String> = files.iter().map(|f| module_of(&src, f)).collect();
    let mut out = BTreeMap::new();
    for f in &files {
        let m = module_of(&src, f);
        let text = code(&std::fs::read_to_string(f).unwrap());
        // `super::` is the parent module, for a `mod.rs` as for any other file.
        let base = m
            .rsplit_once("::")
            .map_or(String::new(), |(p, _)| p.to_string());
        let mut deps = BTreeSet::new();
        for p in paths_after(&text, "crate::") {
            deps.extend(owner(p, &modules));
        }
        for p in paths_after(&text, "super::") {
            let full = if base.is_empty() {
                p.to_string()
            } else {
                format!("{base}::{p}")
            };
            deps.extend(owner(&full, &modules));
        }
        deps.retain(|d| *d != m && !m.starts_with(&format!("{d}::")));
        out.insert(m, deps);
    }
    out
}

#[test]
fn each_layer_imports_only_the_layers_below() {
    let allowed: BTreeMap<&str, &[&str]> = ALLOWED.into_iter().collect();
    for (m, deps) in imports() {
        let Some(top) = m.split("::").next().filter(|t| !t.is_empty()) else {
            continue;
        };
        let ok = allowed
            .get(top)
            .unwrap_or_else(|| panic!("{top} is not in ALLOWED: name its layer"));
        for d in deps {
            let dtop = d.split("::").next().unwrap_or("");
            assert!(
                dtop == top || ok.contains(&dtop),
                "{m} imports {d}: {top} may import only {ok:?}"
            );
        }
    }
}

#[test]
fn no_module_imports_one_that_imports_it_back() {
    let map = imports();
    assert!(map.len() > 40, "modules found: {}", map.len());
    for (a, deps) in &map {
        for b in deps {
            assert!(
                !map.get(b).is_some_and(|d| d.contains(a)),
                "{a} and {b} import each other"
            );
        }
    }
}
