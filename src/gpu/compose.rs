//! The WGSL module system: a kernel names the shared modules it uses with `#import NAME` lines
//! (`shaders/shared/NAME.wgsl`), and composing it gives one WGSL text with each module once,
//! every module before the code that imports it, and a map from each composed line back to its
//! file and line, so that errors name the file a person edits. `#import store` is the block
//! store module of the build (one of `STORE_MODULES`).
//!
//! `build.rs` composes and validates every kernel with this code (docs/ARCHITECTURE.md,
//! Shaders), so it uses nothing of the crate but `std` and naga.

use std::collections::{HashMap, HashSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A composed kernel: its WGSL text and where each line came from.
#[derive(Clone, Debug)]
pub struct Composed {
    pub text: String,
    /// `origin[i]`: (file relative to the shader folder, 1-based line) of composed line `i + 1`.
    pub origin: Vec<(String, u32)>,
}

impl Composed {
    /// `file:line` of a 1-based composed line.
    pub fn locate(&self, line: u32) -> String {
        match self.origin.get(line.saturating_sub(1) as usize) {
            Some((file, l)) => format!("{file}:{l}"),
            None => format!("<composed>:{line}"),
        }
    }
}

/// Reads shader files; the build reads them from disk, tests may compose from memory.
pub trait Files {
    fn read(&self, name: &str) -> Result<String, String>;
}

/// Shader files under a folder on disk.
pub struct Dir(pub PathBuf);

impl Files for Dir {
    fn read(&self, name: &str) -> Result<String, String> {
        let path = self.0.join(name);
        std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))
    }
}

/// Files on disk, with some replaced by text in memory (tests break a shader this way).
pub struct Overlay {
    pub dir: Dir,
    pub replaced: HashMap<String, String>,
}

impl Files for Overlay {
    fn read(&self, name: &str) -> Result<String, String> {
        match self.replaced.get(name) {
            Some(text) => Ok(text.clone()),
            None => self.dir.read(name),
        }
    }
}

/// The block store modules `#import store` may name; every kernel is composed once for each:
/// one texture, a texture store in parts (larger than one resource may be), one buffer.
pub const STORE_MODULES: [&str; 3] = ["store_texture", "store_texture_parts", "store_buffer"];

/// The shared module file an import names.
pub fn module_file(name: &str, store: &str) -> String {
    let name = if name == "store" { store } else { name };
    format!("shared/{name}.wgsl")
}

/// Composes `kernel` (a file name such as `traverse.wgsl`) with the block store module `store`.
pub fn compose(files: &dyn Files, kernel: &str, store: &str) -> Result<Composed, String> {
    let mut out = Composed {
        text: String::new(),
        origin: Vec::new(),
    };
    let mut done = HashSet::new();
    let mut stack = Vec::new();
    append(files, kernel, store, &mut out, &mut done, &mut stack)?;
    Ok(out)
}

fn append(
    files: &dyn Files,
    file: &str,
    store: &str,
    out: &mut Composed,
    done: &mut HashSet<String>,
    stack: &mut Vec<String>,
) -> Result<(), String> {
    if stack.iter().any(|f| f == file) {
        return Err(format!(
            "shaders/{file}: import cycle {} -> {file}",
            stack.join(" -> ")
        ));
    }
    if !done.insert(file.to_string()) {
        return Ok(());
    }
    let text = files.read(file)?;
    stack.push(file.to_string());
    let mut body = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let n = i as u32 + 1;
        match line.trim().strip_prefix("#import") {
            Some(rest) => {
                let name = rest.trim();
                let valid =
                    !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
                if !valid {
                    return Err(format!("shaders/{file}:{n}: bad import '{}'", line.trim()));
                }
                // An import is only allowed before the module's own code.
                if !body.is_empty() {
                    return Err(format!(
                        "shaders/{file}:{n}: #import {name} after code: imports come first"
                    ));
                }
                append(files, &module_file(name, store), store, out, done, stack)
                    .map_err(|e| format!("{e}\n  imported from shaders/{file}:{n}"))?;
            }
            None => {
                let code = line.trim();
                if !code.is_empty() && !code.starts_with("//") {
                    body.push(n);
                }
                out.text.push_str(line);
                out.text.push('\n');
                out.origin.push((file.to_string(), n));
            }
        }
    }
    stack.pop();
    Ok(())
}

/// Parses and validates a composed kernel with naga, as the driver's front end would; an error
/// names the original file and line (`shaders/FILE:LINE[:COLUMN]: message`) and every labelled
/// place it points to.
pub fn validate(c: &Composed, kernel: &str) -> Result<naga::Module, String> {
    let module = naga::front::wgsl::parse_str(&c.text).map_err(|e| {
        // The first label with a place in the text (some, like a required type, have none).
        let at = e
            .labels()
            .find(|(span, _)| span.is_defined())
            .map(|(span, _)| {
                let l = span.location(&c.text);
                format!("shaders/{}:{}", c.locate(l.line_number), l.line_position)
            })
            .unwrap_or_else(|| format!("shaders/{kernel}"));
        let mut msg = format!("{at}: {} (in kernel {kernel})", e.message());
        for (span, label) in e.labels().filter(|(span, _)| span.is_defined()) {
            let l = span.location(&c.text);
            write!(msg, "\n  shaders/{}: {label}", c.locate(l.line_number)).unwrap();
        }
        msg
    })?;
    // Subgroup operations: the device is opened with them (gpu::Gpu::new).
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default() | naga::valid::Capabilities::SUBGROUP,
    )
    .validate(&module)
    .map_err(|e| {
        let at = e
            .spans()
            .find(|(span, _)| span.is_defined())
            .map(|(span, _)| format!("shaders/{}", c.locate(span.location(&c.text).line_number)))
            .unwrap_or_else(|| format!("shaders/{kernel}"));
        let mut msg = format!("{at}: {} (in kernel {kernel})", e.as_inner());
        let mut source = std::error::Error::source(e.as_inner());
        while let Some(s) = source {
            write!(msg, ": {s}").unwrap();
            source = s.source();
        }
        for (span, label) in e.spans() {
            let l = span.location(&c.text);
            write!(msg, "\n  shaders/{}: {label}", c.locate(l.line_number)).unwrap();
        }
        msg
    })?;
    Ok(module)
}

/// The kernels: every `*.wgsl` directly in the shader folder (shared modules live in
/// `shared/`), sorted by name.
pub fn kernel_files(dir: &Path) -> Result<Vec<String>, String> {
    let mut names = Vec::new();
    let list = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for entry in list {
        let entry = entry.map_err(|e| format!("{}: {e}", dir.display()))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.ends_with(".wgsl") && entry.path().is_file() {
            names.push(name);
        }
    }
    names.sort();
    Ok(names)
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Mem(HashMap<&'static str, &'static str>);

    impl Files for Mem {
        fn read(&self, name: &str) -> Result<String, String> {
            self.0
                .get(name)
                .map(|s| s.to_string())
                .ok_or_else(|| format!("{name}: not found"))
        }
    }

    fn mem(files: &[(&'static str, &'static str)]) -> Mem {
        Mem(files.iter().copied().collect())
    }

    #[test]
    fn modules_come_once_and_before_their_users() {
        let files = mem(&[
            ("k.wgsl", "#import b\n#import a\nfn main() {}\n"),
            ("shared/a.wgsl", "fn a() {}\n"),
            ("shared/b.wgsl", "#import a\nfn b() { a(); }\n"),
        ]);
        let c = compose(&files, "k.wgsl", "store_texture").unwrap();
        assert_eq!(c.text, "fn a() {}\nfn b() { a(); }\nfn main() {}\n");
        assert_eq!(c.locate(1), "shared/a.wgsl:1");
        assert_eq!(c.locate(2), "shared/b.wgsl:2");
        assert_eq!(c.locate(3), "k.wgsl:3");
    }

    #[test]
    fn store_import_follows_the_build() {
        let files = mem(&[
            ("k.wgsl", "#import store\n"),
            ("shared/store_buffer.wgsl", "// buffer\n"),
        ]);
        let c = compose(&files, "k.wgsl", "store_buffer").unwrap();
        assert_eq!(c.text, "// buffer\n");
        assert!(compose(&files, "k.wgsl", "store_texture").is_err());
    }

    #[test]
    fn cycles_missing_modules_and_late_imports_are_errors() {
        let files = mem(&[
            ("k.wgsl", "#import a\n"),
            ("shared/a.wgsl", "#import b\n"),
            ("shared/b.wgsl", "#import a\n"),
            ("late.wgsl", "fn f() {}\n#import a\n"),
            ("bad.wgsl", "#import a-b\n"),
        ]);
        let e = compose(&files, "k.wgsl", "s").unwrap_err();
        assert!(e.contains("import cycle"), "{e}");
        let e = compose(&files, "late.wgsl", "s").unwrap_err();
        assert!(e.contains("late.wgsl:2"), "{e}");
        let e = compose(&files, "bad.wgsl", "s").unwrap_err();
        assert!(e.contains("bad.wgsl:1: bad import"), "{e}");
        let e = compose(&mem(&[("k.wgsl", "#import nope\n")]), "k.wgsl", "s").unwrap_err();
        assert!(
            e.contains("shared/nope.wgsl") && e.contains("k.wgsl:1"),
            "{e}"
        );
    }
}
