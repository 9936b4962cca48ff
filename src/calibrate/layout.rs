//! A calibration as character-file TOML: a `[[markers]]` entry per placed label (its
//! bone and offset) and `[calibration] marker_scale`. Written into an existing file, the
//! file's other tables, keys and comments are kept; its old `[[markers]]` are replaced.

use super::Calibration;
use toml_edit::{value, Array, ArrayOfTables, DocumentMut, Item, Table};

/// Millimetre precision: offsets are written to 0.1 mm.
fn rounded(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

/// The `[[markers]]` tables of a calibration, in the take's label order.
fn marker_tables(cal: &Calibration) -> ArrayOfTables {
    let mut out = ArrayOfTables::new();
    for p in &cal.placed {
        let mut t = Table::new();
        t.insert("name", value(p.label.as_str()));
        t.insert("bone", value(p.joint_name.as_str()));
        let mut a = Array::new();
        for c in p.offset_m.to_array() {
            a.push(rounded(c));
        }
        t.insert("offset_m", value(a));
        out.push(t);
    }
    out
}

/// Why a character file cannot take the calibration.
#[derive(Debug, thiserror::Error)]
pub enum LayoutError {
    #[error("{path}: not TOML: {source}")]
    Parse {
        path: String,
        source: toml_edit::TomlError,
    },
    #[error("{path}: `{key}` is not a table")]
    NotATable { path: String, key: &'static str },
}

/// `text` (a character file named `path`) with its `[[markers]]` replaced by the
/// calibration's and `[calibration] marker_scale` set.
pub fn write_into(text: &str, path: &str, cal: &Calibration) -> Result<String, LayoutError> {
    let mut doc: DocumentMut = text.parse().map_err(|source| LayoutError::Parse {
        path: path.to_owned(),
        source,
    })?;
    doc.remove("markers");
    let calibration = doc
        .entry("calibration")
        .or_insert_with(|| Item::Table(Table::new()));
    let Some(table) = calibration.as_table_mut() else {
        return Err(LayoutError::NotATable {
            path: path.to_owned(),
            key: "calibration",
        });
    };
    table.insert("marker_scale", value((cal.scale * 1e5).round() / 1e5));
    doc.insert("markers", Item::ArrayOfTables(marker_tables(cal)));
    Ok(doc.to_string())
}

/// The calibration alone, as the TOML a character file would hold.
pub fn to_toml(cal: &Calibration) -> String {
    let mut doc = DocumentMut::new();
    let mut t = Table::new();
    t.insert("marker_scale", value((cal.scale * 1e5).round() / 1e5));
    doc.insert("calibration", Item::Table(t));
    doc.insert("markers", Item::ArrayOfTables(marker_tables(cal)));
    doc.to_string()
}
