//! Marker names to indices: how an input's labels (a stream's marker names, a
//! recording's labels, VRPN sensors) find the character's markers. A name matches
//! exactly, or else without case and without a `Subject:` prefix (`Bob:LFHD` is `lfhd`).
//! A fixed index knows the character's names only; a growing one (`rigless listen`,
//! which has no character) gives every new name the next index, up to a bound.

use std::collections::HashMap;

/// Longest name a growing index takes, bytes (names come from the network).
pub const MAX_NAME_BYTES: usize = 256;

/// Marker indices by name.
#[derive(Clone, Debug)]
pub struct MarkerIndex {
    names: Vec<String>,
    exact: HashMap<String, u32>,
    /// Loose names (a fixed index only).
    loose: HashMap<String, u32>,
    /// For a growing index, the most names it takes (later new names get no index).
    grow_up_to: Option<usize>,
    /// Scratch for a loose name, so that a lookup does not allocate once warm.
    scratch: String,
}

/// A name as it matches loosely: its part after the last `:`, trimmed, lower case.
pub fn bare_name(name: &str) -> String {
    let mut out = String::new();
    bare_name_into(name, &mut out);
    out
}

/// [`bare_name`] into `out` (cleared first).
fn bare_name_into(name: &str, out: &mut String) {
    out.clear();
    let bare = name.rsplit(':').next().unwrap_or(name).trim();
    out.extend(bare.chars().map(|c| c.to_ascii_lowercase()));
}

impl MarkerIndex {
    /// The character's markers, `names[k]` at index `k`. A loose name shared by several
    /// markers goes to the first.
    pub fn fixed(names: &[String]) -> Self {
        let mut index = Self {
            names: Vec::with_capacity(names.len()),
            exact: HashMap::with_capacity(names.len()),
            loose: HashMap::with_capacity(names.len()),
            grow_up_to: None,
            scratch: String::new(),
        };
        for n in names {
            index.insert(n);
        }
        index
    }

    /// An empty index that gives each new name the next index, up to `max_names` names
    /// of at most [`MAX_NAME_BYTES`] (a bound on memory for names read from the
    /// network).
    pub fn growing(max_names: usize) -> Self {
        Self {
            names: Vec::new(),
            exact: HashMap::new(),
            loose: HashMap::new(),
            grow_up_to: Some(max_names),
            scratch: String::new(),
        }
    }

    fn insert(&mut self, name: &str) -> u32 {
        let k = self.names.len() as u32;
        self.names.push(name.to_owned());
        self.exact.entry(name.to_owned()).or_insert(k);
        if self.grow_up_to.is_none() {
            self.loose.entry(bare_name(name)).or_insert(k);
        }
        k
    }

    /// The index of `name`, if it matches (exactly, or loosely) a known marker.
    pub fn get(&self, name: &str) -> Option<u32> {
        self.exact
            .get(name)
            .or_else(|| self.loose.get(&bare_name(name)))
            .copied()
    }

    /// [`Self::get`] without allocating once warm (the inputs call it per sample); a
    /// growing index with room left also takes a new name (matched exactly only, so that
    /// `A` and `a` stay two markers of a stream).
    pub fn resolve(&mut self, name: &str) -> Option<u32> {
        if let Some(&k) = self.exact.get(name) {
            return Some(k);
        }
        match self.grow_up_to {
            None => {
                bare_name_into(name, &mut self.scratch);
                self.loose.get(&self.scratch).copied()
            }
            Some(max) if self.names.len() < max && name.len() <= MAX_NAME_BYTES => {
                Some(self.insert(name))
            }
            Some(_) => None,
        }
    }

    /// Every known name, by index.
    pub fn names(&self) -> &[String] {
        &self.names
    }
}

/// How a recording's labels feed a character's markers.
#[derive(Clone, Debug, PartialEq)]
pub struct LabelMap {
    /// For each label (in the recording's order), the marker it feeds.
    pub marker_of_label: Vec<Option<u32>>,
    /// Labels that match no marker (ignored).
    pub unmatched_labels: Vec<String>,
    /// Markers no label feeds (they stay held).
    pub unfed_markers: Vec<String>,
}

impl LabelMap {
    /// Maps `labels` onto the markers of `index` ([`MarkerIndex::get`]).
    pub fn new(labels: &[String], index: &MarkerIndex) -> Self {
        let marker_of_label: Vec<Option<u32>> = labels.iter().map(|l| index.get(l)).collect();
        let unmatched_labels = labels
            .iter()
            .zip(&marker_of_label)
            .filter(|(_, m)| m.is_none())
            .map(|(l, _)| l.clone())
            .collect();
        let unfed_markers = index
            .names()
            .iter()
            .enumerate()
            .filter(|(k, _)| !marker_of_label.contains(&Some(*k as u32)))
            .map(|(_, m)| m.clone())
            .collect();
        Self {
            marker_of_label,
            unmatched_labels,
            unfed_markers,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn names_match_exactly_then_without_case_or_subject() {
        let index = MarkerIndex::fixed(&names(&["LFHD", "RFHD", "lfhd"]));
        assert_eq!(index.get("LFHD"), Some(0));
        assert_eq!(index.get("lfhd"), Some(2), "an exact match wins");
        assert_eq!(index.get("Bob:RFHD"), Some(1));
        assert_eq!(index.get(" rfhd "), Some(1));
        assert_eq!(
            index.get("Bob:LFHD"),
            Some(0),
            "first of a shared loose name"
        );
        assert_eq!(index.get("C7"), None);
    }

    #[test]
    fn a_growing_index_takes_new_names_up_to_its_bound() {
        let mut index = MarkerIndex::growing(2);
        assert_eq!(index.resolve("A"), Some(0));
        assert_eq!(index.resolve("a"), Some(1), "exact names only");
        assert_eq!(index.resolve("A"), Some(0));
        assert_eq!(index.resolve("B"), None, "full");
        assert_eq!(index.names(), &names(&["A", "a"])[..]);
        let mut index = MarkerIndex::growing(10);
        assert_eq!(
            index.resolve(&"x".repeat(MAX_NAME_BYTES + 1)),
            None,
            "too long"
        );
        assert_eq!(index.resolve(&"x".repeat(MAX_NAME_BYTES)), Some(0));
        let mut fixed = MarkerIndex::fixed(&names(&["A"]));
        assert_eq!(fixed.resolve("B"), None, "a fixed index never grows");
        assert_eq!(
            fixed.resolve("Sub:a"),
            Some(0),
            "resolve matches loosely too"
        );
        assert_eq!(fixed.names().len(), 1);
    }

    #[test]
    fn labels_map_onto_markers_and_say_what_is_left() {
        let index = MarkerIndex::fixed(&names(&["wrist", "index_nail", "thumb_nail"]));
        let map = LabelMap::new(&names(&["Sub:WRIST", "C7", "index_nail"]), &index);
        assert_eq!(map.marker_of_label, vec![Some(0), None, Some(1)]);
        assert_eq!(map.unmatched_labels, names(&["C7"]));
        assert_eq!(map.unfed_markers, names(&["thumb_nail"]));
        // Vicon writes `Subject:LFHD`.
        let index = MarkerIndex::fixed(&names(&["C7", "LFHD", "RFHD", "T10"]));
        let map = LabelMap::new(&names(&["Subject:LFHD", "rfhd", "C7", "extra"]), &index);
        assert_eq!(map.marker_of_label, vec![Some(1), Some(2), Some(0), None]);
        assert_eq!(map.unmatched_labels, names(&["extra"]));
        assert_eq!(map.unfed_markers, names(&["T10"]));
    }
}
