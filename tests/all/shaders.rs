//! The shader module system: every kernel in `shaders/` was composed and validated by the build,
//! and a broken shader is reported at its own file and line.

use crate::common::repo;
use dcrt::gpu::compose::{self, Dir, Overlay};
use dcrt::gpu::shaders::{self, Store};
use std::collections::HashMap;

fn shader_dir() -> std::path::PathBuf {
    repo().join("shaders")
}

#[test]
fn the_build_composed_every_kernel_for_every_store() {
    let files = compose::kernel_files(&shader_dir()).unwrap();
    assert!(files.len() >= 8, "{files:?}");
    for f in &files {
        let name = f.trim_end_matches(".wgsl");
        for store in compose::STORE_MODULES {
            let k = shaders::kernel(name, store);
            // What the build embedded is what composing the files gives now.
            let c = compose::compose(&Dir(shader_dir()), f, store).unwrap();
            assert_eq!(k.source, c.text, "kernel {name} ({store}) is stale");
            compose::validate(&c, f).unwrap();
        }
    }
    // Every store the user may choose has its module.
    for store in Store::ALL {
        assert!(
            compose::STORE_MODULES.contains(&store.module()),
            "{store:?}"
        );
    }
    assert_eq!(
        shaders::KERNELS.len(),
        files.len() * compose::STORE_MODULES.len()
    );
}

/// Composes `kernel` with `file` replaced by `text`, and validates it.
fn broken(kernel: &str, file: &str, text: String) -> String {
    let files = Overlay {
        dir: Dir(shader_dir()),
        replaced: HashMap::from([(file.to_string(), text)]),
    };
    let c = compose::compose(&files, kernel, "store_texture").unwrap();
    compose::validate(&c, kernel).expect_err("a broken shader validated")
}

/// The text of `file` with `line` inserted after its line `after`.
fn with_line(file: &str, after: usize, line: &str) -> String {
    let text = std::fs::read_to_string(shader_dir().join(file)).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines.insert(after, line);
    lines.join("\n") + "\n"
}

#[test]
fn errors_name_the_file_and_line_of_every_kernel_and_module() {
    let dir = shader_dir();
    let mut modules: Vec<String> = std::fs::read_dir(dir.join("shared"))
        .unwrap()
        .map(|e| format!("shared/{}", e.unwrap().file_name().to_string_lossy()))
        .filter(|f| {
            f.ends_with(".wgsl")
                && !f.contains("store_buffer")
                && !f.contains("store_texture_parts")
        })
        .collect();
    modules.sort();
    let kernels = compose::kernel_files(&dir).unwrap();
    // A syntax error in each kernel, after its imports.
    for k in &kernels {
        let text = std::fs::read_to_string(dir.join(k)).unwrap();
        let at = text.lines().position(|l| l.starts_with("@")).unwrap_or(1);
        let e = broken(k, k, with_line(k, at, "fn broken( {"));
        assert!(
            e.starts_with(&format!("shaders/{k}:{}:", at + 1)),
            "{k}: {e}"
        );
    }
    // A type error in each shared module, seen through a kernel that imports it.
    for m in &modules {
        let name = m.trim_start_matches("shared/").trim_end_matches(".wgsl");
        let user = kernels
            .iter()
            .find(|k| {
                let c = compose::compose(&Dir(dir.clone()), k, "store_texture").unwrap();
                c.origin.iter().any(|(f, _)| f == m)
            })
            .unwrap_or_else(|| panic!("no kernel imports {name}"));
        let n = std::fs::read_to_string(dir.join(m))
            .unwrap()
            .lines()
            .count();
        let e = broken(
            user,
            m,
            with_line(m, n, "fn broken() -> u32 { return 1.5; }"),
        );
        assert!(e.starts_with(&format!("shaders/{m}:{}", n + 1)), "{m}: {e}");
    }
}
