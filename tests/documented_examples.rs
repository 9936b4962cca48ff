//! The TOML examples the documentation shows are read as it says: every ```toml block of
//! README.md and docs/ that is a stage config parses as one, and every one that is a
//! character file has only known keys.

use std::path::Path;

/// The ```toml blocks of a Markdown file, with the line each starts at.
fn toml_blocks(path: &Path) -> Vec<(usize, String)> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut blocks = Vec::new();
    let mut current: Option<(usize, String)> = None;
    for (n, line) in text.lines().enumerate() {
        match (&mut current, line.trim()) {
            (None, "```toml") => current = Some((n + 2, String::new())),
            (Some(_), "```") => blocks.extend(current.take()),
            (Some((_, b)), _) => {
                b.push_str(line);
                b.push('\n');
            }
            (None, _) => {}
        }
    }
    blocks
}

#[test]
fn the_documented_toml_examples_read_as_documented() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![root.join("README.md")];
    for e in std::fs::read_dir(root.join("docs")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "md") {
            files.push(p);
        }
    }
    let (mut stages, mut characters) = (0, 0);
    for f in &files {
        for (line, block) in toml_blocks(f) {
            let at = format!("{}:{line}", f.display());
            if block.contains("[character]") || block.contains("[[inputs]]") {
                rigless::config::parse_stage(&block, &at).unwrap_or_else(|e| panic!("{e}"));
                stages += 1;
            } else if block.contains("[mesh]") {
                if let Err(problems) = rigless::character::file::read_spec(&block) {
                    panic!("{at}: {problems:#?}");
                }
                characters += 1;
            }
        }
    }
    // README.md shows one of each.
    assert!(
        stages >= 1 && characters >= 1,
        "{stages} stage and {characters} character examples"
    );
}
