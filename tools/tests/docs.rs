//! The documents say what the code does: checks of the docs against the repository itself (the
//! crate graph of `docs/architecture.md` against the `Cargo.toml` files). Must never: read
//! anything outside the repository, or need the network.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

fn root() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// A crate's short name in the picture: its folder's (`rt` for `rt-loop`).
fn short(folder: &str) -> String {
    if folder == "rt-loop" {
        "rt".into()
    } else {
        folder.into()
    }
}

/// Every member crate (short name) and the members it depends on (normal dependencies only).
fn crate_graph() -> BTreeMap<String, BTreeSet<String>> {
    let text = std::fs::read_to_string(root().join("Cargo.toml")).unwrap();
    let line = text.lines().find(|l| l.starts_with("members")).unwrap();
    let folders: Vec<String> = line.split('"').skip(1).step_by(2).map(String::from).collect();
    let package = |folder: &str| {
        let t = std::fs::read_to_string(root().join(folder).join("Cargo.toml")).unwrap();
        let name =
            t.lines().find_map(|l| l.strip_prefix("name = \"")).unwrap().trim_end_matches('"').to_string();
        (name, t)
    };
    let names: BTreeMap<String, String> = folders.iter().map(|f| (package(f).0, short(f))).collect();
    let mut g = BTreeMap::new();
    for f in &folders {
        let (_, t) = package(f);
        let mut deps = BTreeSet::new();
        let mut in_deps = false;
        for l in t.lines() {
            if l.starts_with('[') {
                in_deps = l.trim() == "[dependencies]";
            } else if in_deps {
                let key = l.split(['.', ' ', '=']).next().unwrap_or("");
                if let Some(s) = names.get(key) {
                    deps.insert(s.clone());
                }
            }
        }
        g.insert(short(f), deps);
    }
    g
}

/// The edges a reader needs: those not implied by a longer path.
fn reduced(g: &BTreeMap<String, BTreeSet<String>>) -> BTreeSet<(String, String)> {
    let reach = |from: &str| {
        let (mut seen, mut todo) = (BTreeSet::new(), vec![from.to_string()]);
        while let Some(x) = todo.pop() {
            for y in &g[&x] {
                if seen.insert(y.clone()) {
                    todo.push(y.clone());
                }
            }
        }
        seen
    };
    let mut out = BTreeSet::new();
    for (a, ds) in g {
        for b in ds {
            if !ds.iter().any(|c| c != b && reach(c).contains(b)) {
                out.insert((a.clone(), b.clone()));
            }
        }
    }
    out
}

/// The arrows of the mermaid picture under "## The crates".
fn pictured() -> BTreeSet<(String, String)> {
    let doc = std::fs::read_to_string(root().join("docs/architecture.md")).unwrap();
    let start = doc.find("## The crates").unwrap();
    let body = &doc[start..];
    let graph = &body[body.find("```mermaid").unwrap()..];
    let graph = &graph[..3 + graph[3..].find("```").unwrap()];
    graph
        .lines()
        .filter_map(|l| l.split_once("-->"))
        .map(|(a, b)| {
            let id = |s: &str| s.trim().split(['[', ' ']).next().unwrap().to_string();
            (id(a), id(b))
        })
        .collect()
}

#[test]
fn the_crate_graph_of_the_architecture_is_the_cargo_one() {
    let want = reduced(&crate_graph());
    let drawn = pictured();
    let missing: Vec<_> = want.difference(&drawn).collect();
    let extra: Vec<_> = drawn.difference(&want).collect();
    assert!(
        missing.is_empty() && extra.is_empty(),
        "docs/architecture.md's crate graph: missing {missing:?}, not in Cargo.toml {extra:?}"
    );
    assert!(want.len() > 10, "{want:?}");
}
