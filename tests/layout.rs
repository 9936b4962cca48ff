//! The crate's layout holds: a folder imports only the folders below it in DESIGN.md's
//! order (so there is no cycle between folders), every module opens with a `//!` line
//! saying what it owns, and no function outside tests is much over 150 lines.

use std::path::{Path, PathBuf};

/// Top to bottom; a module may use those after it. `geom` and `runtime` are the ground
/// floor (geom's tests use runtime's seeded generator; runtime uses nothing). `bench`
/// runs whole stages, so it sits on top.
const FLOORS: &[&[&str]] = &[
    &["bench"],
    &["daemon"],
    &["config"],
    &["output"],
    &["input"],
    &["replay"],
    &["protocol"],
    &["calibrate"],
    &["solve"],
    &["rig"],
    &["character"],
    &["markers"],
    &["geom"],
    &["runtime"],
];

fn floor_of(module: &str) -> Option<usize> {
    FLOORS.iter().position(|f| f.contains(&module))
}

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The top-level module a file of `src/` belongs to (`None` for lib.rs, main.rs, cli/).
fn module_of(file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src()).unwrap();
    let first = rel
        .components()
        .next()?
        .as_os_str()
        .to_string_lossy()
        .into_owned();
    let name = first.trim_end_matches(".rs").to_owned();
    (!["lib", "main", "cli"].contains(&name.as_str())).then_some(name)
}

/// The code of a line, without its comment.
fn code(line: &str) -> &str {
    line.split("//").next().unwrap_or("")
}

#[test]
fn folders_import_only_the_floors_below_them() {
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let mut wrong = Vec::new();
    for f in &files {
        let Some(from) = module_of(f) else { continue };
        let from_floor = floor_of(&from).unwrap_or_else(|| panic!("{from} is in no floor"));
        let text = std::fs::read_to_string(f).unwrap();
        for (n, line) in text.lines().enumerate() {
            let c = code(line);
            for (i, _) in c.match_indices("crate::") {
                let target: String = c[i + 7..]
                    .chars()
                    .take_while(|ch| ch.is_alphanumeric() || *ch == '_')
                    .collect();
                if target == from || target.is_empty() {
                    continue;
                }
                let ok = floor_of(&target).is_some_and(|t| t > from_floor);
                if !ok {
                    wrong.push(format!(
                        "{}:{}: {from} uses {target}",
                        f.strip_prefix(src()).unwrap().display(),
                        n + 1
                    ));
                }
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports against the layout:\n{}",
        wrong.join("\n")
    );
}

#[test]
fn every_module_says_what_it_owns() {
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let missing: Vec<String> = files
        .iter()
        .filter(|f| {
            let text = std::fs::read_to_string(f).unwrap();
            !text.trim_start().starts_with("//!")
        })
        .map(|f| f.display().to_string())
        .collect();
    assert!(missing.is_empty(), "no //! opening: {missing:?}");
}

/// Functions over this many lines (signature to closing brace) outside `#[cfg(test)]`
/// modules are refused: the code style's "about 150 lines", with room for a doc block.
const MAX_FUNCTION_LINES: usize = 160;

#[test]
fn no_function_is_over_about_150_lines() {
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let mut long = Vec::new();
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let end = lines
            .iter()
            .position(|l| l.trim_start().starts_with("#[cfg(test)]"))
            .unwrap_or(lines.len());
        let mut i = 0;
        while i < end {
            let l = lines[i];
            let trimmed = l.trim_start();
            let indent = l.len() - trimmed.len();
            let is_fn = trimmed.starts_with("fn ")
                || trimmed.starts_with("pub fn ")
                || trimmed.starts_with("pub(crate) fn ")
                || trimmed.starts_with("pub(super) fn ")
                || trimmed.starts_with("unsafe fn ")
                || trimmed.starts_with("pub unsafe fn ");
            if !is_fn || trimmed.ends_with(';') {
                i += 1;
                continue;
            }
            // The body ends at the first `}` line at the signature's indentation.
            let close = " ".repeat(indent) + "}";
            let Some(len) = lines[i + 1..end].iter().position(|x| *x == close) else {
                i += 1;
                continue;
            };
            if len + 2 > MAX_FUNCTION_LINES {
                long.push(format!(
                    "{}:{}: {} lines",
                    f.strip_prefix(src()).unwrap().display(),
                    i + 1,
                    len + 2
                ));
            }
            i += 1;
        }
    }
    assert!(long.is_empty(), "functions too long:\n{}", long.join("\n"));
}
