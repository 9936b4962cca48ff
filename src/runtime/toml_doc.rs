//! TOML documents (stage configs, character files) read the way a user needs them read:
//! every problem at once, each at its line. [`Lines`] knows where every key is in the
//! text; [`typed`] deserializes a value and, for each unknown key at any depth, reports
//! it, leaves it out and tries again, so one stray key does not hide the others.

use serde::de::DeserializeOwned;
use serde_path_to_error::Segment;

/// Where keys are in the text: `(table path, key) -> line`, with table paths such as
/// `solver`, `inputs[1]`, `outputs.stream` (dotted keys are joined onto the table).
pub struct Lines {
    keys: Vec<(String, usize)>,
}

impl Lines {
    /// Scans `text` for table headers and keys.
    pub fn scan(text: &str) -> Self {
        let mut keys = Vec::new();
        let mut table = String::new();
        let mut arrays: Vec<(String, usize)> = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let line = raw.trim();
            let n = i + 1;
            if let Some(name) = line.strip_prefix("[[").and_then(|l| l.split("]]").next()) {
                let name = name.trim().to_owned();
                let idx = match arrays.iter_mut().find(|(a, _)| *a == name) {
                    Some((_, c)) => {
                        *c += 1;
                        *c
                    }
                    None => {
                        arrays.push((name.clone(), 0));
                        0
                    }
                };
                table = format!("{name}[{idx}]");
                keys.push((table.clone(), n));
            } else if let Some(name) = line.strip_prefix('[').and_then(|l| l.split(']').next()) {
                table = name.trim().to_owned();
                keys.push((table.clone(), n));
            } else if let Some((k, _)) = line.split_once('=') {
                let k = k.trim().trim_matches('"');
                if !k.is_empty() && !k.starts_with('#') {
                    let full = if table.is_empty() {
                        k.to_owned()
                    } else {
                        format!("{table}.{k}")
                    };
                    keys.push((full, n));
                }
            }
        }
        Self { keys }
    }

    /// The line of `path` (a key or table), or of its nearest enclosing table.
    pub fn of(&self, path: &str) -> Option<usize> {
        let mut p = path;
        loop {
            if let Some((_, n)) = self.keys.iter().find(|(k, _)| k == p) {
                return Some(*n);
            }
            p = &p[..p.rfind(['.', '['])?];
        }
    }

    /// `line N: PATH: WHAT`, or `PATH: WHAT` when the line is not known.
    pub fn at(&self, path: &str, what: impl std::fmt::Display) -> String {
        match self.of(path) {
            Some(n) => format!("line {n}: {path}: {what}"),
            None => format!("{path}: {what}"),
        }
    }
}

/// A syntax error's message with its line (`line N: ...`).
pub fn syntax_error(text: &str, e: &toml::de::Error) -> String {
    let line = e
        .span()
        .map(|s| text[..s.start.min(text.len())].lines().count().max(1));
    let msg = e.message().trim().to_owned();
    match line {
        Some(n) => format!("line {n}: {msg}"),
        None => msg,
    }
}

/// Sorts problems `line N: ...` in file order; problems without a line go last.
pub fn in_file_order(problems: &mut [String]) {
    let line_of = |p: &String| {
        p.strip_prefix("line ")
            .and_then(|r| r.split(':').next())
            .and_then(|n| n.parse::<usize>().ok())
            .unwrap_or(usize::MAX)
    };
    problems.sort_by_key(line_of);
}

/// The field a serde error names (`unknown field `x`` or `missing field `x``), if any.
fn named_field(message: &str) -> Option<&str> {
    let rest = message.split("field `").nth(1)?;
    rest.split('`').next()
}

/// `prefix` joined with a serde path: `a.b[2].c`.
fn joined(prefix: &str, path: &serde_path_to_error::Path) -> String {
    let mut out = prefix.to_owned();
    for s in path {
        match s {
            Segment::Map { key } => {
                if !out.is_empty() {
                    out.push('.');
                }
                out.push_str(key);
            }
            Segment::Seq { index } => out.push_str(&format!("[{index}]")),
            Segment::Enum { .. } | Segment::Unknown => {}
        }
    }
    out
}

/// Removes the key the path ends at from `v` (the path's tables and arrays followed from
/// the root); whether it was there.
fn remove_at(v: &mut toml::Value, path: &serde_path_to_error::Path) -> bool {
    let segments: Vec<&Segment> = path.iter().collect();
    let Some((Segment::Map { key }, parents)) = segments.split_last() else {
        return false;
    };
    let mut at = v;
    for s in parents {
        at = match (s, at) {
            (Segment::Map { key }, toml::Value::Table(t)) => match t.get_mut(key) {
                Some(next) => next,
                None => return false,
            },
            (Segment::Seq { index }, toml::Value::Array(a)) => match a.get_mut(*index) {
                Some(next) => next,
                None => return false,
            },
            _ => return false,
        };
    }
    at.as_table_mut().is_some_and(|t| t.remove(key).is_some())
}

/// Most unknown keys one value may hold before the rest are not looked for.
const MAX_UNKNOWN_KEYS: usize = 64;

/// Deserializes `value` (found at `at`, `""` for the document) into `T`. Each unknown
/// key, at any depth, is reported at its line and left out, and the rest tried again;
/// any other problem is reported at its line and ends the attempt (`None`).
pub fn typed<T: DeserializeOwned>(
    value: &toml::Value,
    at: &str,
    lines: &Lines,
    problems: &mut Vec<String>,
) -> Option<T> {
    let mut v = value.clone();
    for _ in 0..MAX_UNKNOWN_KEYS {
        let e = match serde_path_to_error::deserialize::<_, T>(v.clone()) {
            Ok(t) => return Some(t),
            Err(e) => e,
        };
        let msg = e.inner().message().trim().to_owned();
        let path = joined(at, e.path());
        let unknown = msg.starts_with("unknown field");
        match named_field(&msg) {
            // Where the path ends at the key itself, that key goes.
            Some(f) if unknown && path.ends_with(f) && remove_at(&mut v, e.path()) => {
                problems.push(lines.at(&path, &msg));
            }
            // Internally tagged enums lose the path: the key is then at this level.
            Some(f) if unknown && v.as_table_mut().is_some_and(|t| t.remove(f).is_some()) => {
                let full = if path.is_empty() {
                    f.to_owned()
                } else {
                    format!("{path}.{f}")
                };
                problems.push(lines.at(&full, &msg));
            }
            _ => {
                problems.push(lines.at(if path.is_empty() { at } else { &path }, msg));
                return None;
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Doc {
        name: String,
        #[serde(default)]
        mesh: Mesh,
        #[serde(default)]
        markers: Vec<Mesh>,
    }

    #[derive(Debug, Default, serde::Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Mesh {
        #[serde(default)]
        path: String,
    }

    fn read(text: &str) -> (Option<Doc>, Vec<String>) {
        let value: toml::Value = toml::from_str(text).unwrap();
        let mut problems = Vec::new();
        let doc = typed::<Doc>(&value, "", &Lines::scan(text), &mut problems);
        (doc, problems)
    }

    #[test]
    fn every_unknown_key_at_any_depth_is_reported_at_its_line() {
        let text = "name = \"x\"\nfoo = 1\nbar = 2\n[mesh]\npath = \"a.obj\"\nbaz = 3\n[[markers]]\npath = \"m\"\n[[markers]]\nqux = 4\n";
        let (doc, problems) = read(text);
        assert_eq!(problems.len(), 4, "{problems:#?}");
        for want in [
            "line 2: foo: unknown field",
            "line 3: bar: unknown field",
            "line 6: mesh.baz: unknown field",
            "line 10: markers[1].qux: unknown field",
        ] {
            assert!(
                problems.iter().any(|p| p.starts_with(want)),
                "{want} in {problems:#?}"
            );
        }
        let doc = doc.expect("the rest reads");
        assert_eq!(doc.mesh.path, "a.obj");
        assert_eq!(doc.markers.len(), 2);
    }

    #[test]
    fn a_wrong_type_is_reported_at_its_line_and_ends_the_attempt() {
        let (doc, problems) = read("name = \"x\"\n[mesh]\npath = 3\n");
        assert!(doc.is_none());
        assert_eq!(problems.len(), 1);
        assert!(
            problems[0].starts_with("line 3: mesh.path: invalid type"),
            "{problems:?}"
        );
    }
}
