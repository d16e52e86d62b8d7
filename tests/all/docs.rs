//! The lists in the documentation that name code stay true: docs/ARCHITECTURE.md's module map
//! names every top-level module of the library and every path it names exists.

use crate::common::repo;
use std::collections::BTreeSet;

/// The entries of the module map's tree: paths relative to the repository (`src/gpu/`,
/// `src/gpu/tracer.rs`, `build.rs`).
fn module_map() -> Vec<String> {
    let text = std::fs::read_to_string(repo().join("docs/ARCHITECTURE.md")).unwrap();
    let map = text
        .split("## Module map")
        .nth(1)
        .expect("a Module map section");
    // The layer diagram's block, then the tree's, which starts at `src/`.
    let block = map
        .split("```")
        .skip(1)
        .step_by(2)
        .find(|b| b.trim_start().starts_with("src/"))
        .expect("the map in a code block");
    let mut entries = Vec::new();
    let (mut dir, mut root) = (String::new(), String::new());
    for line in block.lines().filter(|l| !l.trim().is_empty()) {
        let first = |s: &str| s.split_whitespace().next().unwrap_or("").to_string();
        if let Some(rest) = line
            .strip_prefix("├── ")
            .or_else(|| line.strip_prefix("└── "))
        {
            let name = first(rest);
            match root.as_str() {
                "src" => {
                    dir = format!("src/{}", name.trim_end_matches('/'));
                    entries.push(format!("src/{name}"));
                }
                // Under a path beside src/ (shaders/shared/).
                r => entries.push(format!("{r}/{name}")),
            }
        } else if let Some(rest) = line
            .strip_prefix("│   ├── ")
            .or_else(|| line.strip_prefix("│   └── "))
            .or_else(|| line.strip_prefix("    ├── "))
            .or_else(|| line.strip_prefix("    └── "))
        {
            entries.push(format!("{dir}/{}", first(rest)));
        } else if !line.starts_with(['│', ' ']) {
            // The root (`src/`), then paths beside src/ (build.rs, shaders/, tests/all/).
            let name = first(line);
            root = name.trim_end_matches('/').to_string();
            if name != "src/" {
                entries.push(name);
            }
        }
    }
    entries
}

#[test]
fn the_module_map_names_every_module_and_only_what_exists() {
    let entries = module_map();
    assert!(entries.len() > 30, "parsed {entries:?}");
    for e in &entries {
        assert!(
            repo().join(e).exists(),
            "the module map names {e}, which does not exist"
        );
    }
    let named: BTreeSet<String> = entries
        .iter()
        .filter_map(|e| e.strip_prefix("src/"))
        .map(|e| e.split('/').next().unwrap().to_string())
        .collect();
    for m in std::fs::read_dir(repo().join("src")).unwrap() {
        let name = m.unwrap().file_name().to_string_lossy().into_owned();
        let module = name.trim_end_matches(".rs");
        assert!(
            named.contains(&name) || named.contains(module),
            "src/{name} is missing from the module map in docs/ARCHITECTURE.md"
        );
    }
}

#[test]
fn the_architecture_opens_with_the_layers_and_the_module_map() {
    let text = std::fs::read_to_string(repo().join("docs/ARCHITECTURE.md")).unwrap();
    let first = text.lines().find(|l| l.starts_with("## "));
    assert_eq!(first, Some("## Module map"));
    // The GPU side is mapped file by file: a stage split off must be named.
    let entries = module_map();
    for f in std::fs::read_dir(repo().join("src/gpu")).unwrap() {
        let name = f.unwrap().file_name().to_string_lossy().into_owned();
        if name.ends_with(".rs") {
            let path = format!("src/gpu/{name}");
            assert!(
                entries.contains(&path),
                "{path} is missing from the module map"
            );
        }
    }
}
