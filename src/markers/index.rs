//! Marker names to indices: how an input's labels (a stream's marker names, a
//! recording's labels, VRPN sensors) find the character's markers. A name matches
//! exactly, or else without case and without a `Subject:` prefix (`Bob:LFHD` is `lfhd`).
//! A fixed index knows the character's names only; a growing one (`rigless listen`,
//! which has no character) gives every new name the next index, up to a bound.
//!
//! A character is one performer, so a fixed index takes one subject's labels
//! ([`SubjectFilter`]): `Ann:LFHD` and `Bob:LFHD` in one stream never both feed its
//! `LFHD`. Labels without a prefix are a subject of their own (`""`). The others'
//! samples are refused and counted ([`MarkerIndex::refused`]).
//!
//! A stage of several actors resolves every label with one index over all of them
//! ([`MarkerIndex::for_actors`]): each actor claims labels by subject, by pattern, or
//! (none given) those without a prefix ([`Claim`]); a label goes to the actor that
//! claims it, its marker found within that actor's alone, and comes back as a stage
//! index (the actor's first marker's index plus the marker's). Labels no actor claims
//! are refused and counted like another subject's.

use std::collections::HashMap;

/// Longest name a growing index takes, bytes (names come from the network).
pub const MAX_NAME_BYTES: usize = 256;

/// Most other subjects an index names in its report (names come from the network).
const MAX_OTHER_SUBJECTS: usize = 8;

/// Which subject's labels a fixed index takes.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum SubjectFilter {
    /// One subject, found from the labels: in a stream the first whose label matches a
    /// marker; in a recording ([`LabelMap::new`]) the one with most matching labels.
    #[default]
    One,
    /// This subject's only (`Ann` takes `Ann:LFHD` and `ann:lfhd`; `""` takes labels
    /// without a prefix).
    Named(String),
    /// Every subject's labels, each as its own name (a capture for a stage of several
    /// actors, each of which then takes its own).
    All,
}

/// The subject of a `Subject:Label` name: the part before the last `:`, trimmed; `""`
/// for a name without one.
pub fn subject_of(name: &str) -> &str {
    name.rsplit_once(':').map_or("", |(s, _)| s.trim())
}

/// How an actor of a stage of several recognises its labels.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Claim {
    /// `Subject:Label` labels of this subject (any case): a C3D or TSV subject, a NatNet
    /// asset, a VRPN tracker.
    Subject(String),
    /// Labels matching any of these patterns (any case; `*` any run of characters, `?`
    /// one). With one `*`, a label whose bare name is no marker's is tried by what the
    /// `*` stood for (`Ann_*` finds `LFHD` in `Ann_LFHD`).
    Patterns(Vec<String>),
    /// Labels without a subject prefix.
    Unprefixed,
}

impl Claim {
    /// Whether it claims `name`, whose subject is `subject` ([`subject_of`]).
    pub fn claims(&self, name: &str, subject: &str) -> bool {
        match self {
            Claim::Subject(s) => s.eq_ignore_ascii_case(subject),
            Claim::Patterns(ps) => ps.iter().any(|p| glob_match(p, name)),
            Claim::Unprefixed => subject.is_empty(),
        }
    }

    /// What the `*` of a one-star pattern stood for in `name`, if one such claims it.
    pub fn star_part<'n>(&self, name: &'n str) -> Option<&'n str> {
        let Claim::Patterns(ps) = self else {
            return None;
        };
        ps.iter().find_map(|p| {
            let (pre, post) = p.split_once('*')?;
            if post.contains('*') || !glob_match(p, name) {
                return None;
            }
            name.get(pre.len()..name.len().checked_sub(post.len())?)
        })
    }

    /// How a report names it: `subject "Ann"`, `labels "Ann_*"`, `labels without a prefix`.
    pub fn describe(&self) -> String {
        match self {
            Claim::Subject(s) => format!("subject {s:?}"),
            Claim::Patterns(ps) => format!("labels {}", ps.join(", ")),
            Claim::Unprefixed => "labels without a subject prefix".to_owned(),
        }
    }
}

/// Whether `name` matches `pattern` in any ASCII case: `*` any run, `?` one byte (one
/// character of an ASCII name). At most `pattern × name` steps (a star retried from each
/// later byte), no allocation: it runs per sample.
pub fn glob_match(pattern: &str, name: &str) -> bool {
    let (p, n) = (pattern.as_bytes(), name.as_bytes());
    let (mut pi, mut ni) = (0, 0);
    let mut star: Option<(usize, usize)> = None;
    while ni < n.len() {
        if pi < p.len() && (p[pi] == b'?' || p[pi].eq_ignore_ascii_case(&n[ni])) {
            pi += 1;
            ni += 1;
        } else if pi < p.len() && p[pi] == b'*' {
            star = Some((pi, ni));
            pi += 1;
        } else if let Some((sp, sn)) = star {
            pi = sp + 1;
            ni = sn + 1;
            star = Some((sp, sn + 1));
        } else {
            return false;
        }
    }
    p[pi..].iter().all(|c| *c == b'*')
}

/// One actor's markers within a stage's index.
#[derive(Clone, Debug)]
struct ActorSpan {
    claim: Claim,
    /// Its first marker's stage index.
    start: u32,
    /// Its markers by their own names, and loosely, local indices.
    exact: HashMap<String, u32>,
    loose: HashMap<String, u32>,
}

impl ActorSpan {
    /// The stage index of the marker `name` names in this actor (exact, loose, or by a
    /// pattern's star), using `scratch`.
    fn find(&self, name: &str, scratch: &mut String) -> Option<u32> {
        if let Some(k) = self.exact.get(name) {
            return Some(self.start + k);
        }
        bare_name_into(name, scratch);
        if let Some(k) = self.loose.get(scratch.as_str()) {
            return Some(self.start + k);
        }
        let star = self.claim.star_part(name)?;
        bare_name_into(star, scratch);
        self.loose.get(scratch.as_str()).map(|k| self.start + k)
    }
}

/// An actor's markers and how it claims its labels, for [`MarkerIndex::for_actors`].
#[derive(Clone, Debug)]
pub struct ActorLabels {
    /// Its markers' names as the stage names them (each with its subject:
    /// `Ann:LFHD`).
    pub names: Vec<String>,
    /// Its markers' own names (`LFHD`), as labels are matched.
    pub markers: Vec<String>,
    pub claim: Claim,
}

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
    /// Whose loose matches a fixed index takes.
    filter: SubjectFilter,
    /// The subject taken, once known ([`SubjectFilter::One`] in a stream).
    taken: Option<String>,
    /// Samples refused for coming from another subject.
    refused: u64,
    /// The other subjects seen (at most [`MAX_OTHER_SUBJECTS`]).
    others: Vec<String>,
    /// A stage of several actors: each one's markers (empty: one character).
    actors: Vec<ActorSpan>,
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
        Self::fixed_for(names, SubjectFilter::One)
    }

    /// [`Self::fixed`], taking the labels of the subjects `filter` says.
    pub fn fixed_for(names: &[String], filter: SubjectFilter) -> Self {
        let taken = match &filter {
            SubjectFilter::One | SubjectFilter::All => None,
            SubjectFilter::Named(s) => Some(s.clone()),
        };
        let mut index = Self {
            names: Vec::with_capacity(names.len()),
            exact: HashMap::with_capacity(names.len()),
            loose: HashMap::with_capacity(names.len()),
            grow_up_to: None,
            scratch: String::new(),
            filter,
            taken,
            refused: 0,
            others: Vec::new(),
            actors: Vec::new(),
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
            filter: SubjectFilter::One,
            taken: None,
            refused: 0,
            others: Vec::new(),
            actors: Vec::new(),
        }
    }

    /// The index of a stage of several actors: their markers one after the other (the
    /// first actor's from 0), each label going to the actor that claims it (the first
    /// listed, when several would).
    pub fn for_actors(actors: &[ActorLabels]) -> Self {
        let mut index = Self::growing(0);
        index.grow_up_to = None;
        for a in actors {
            let start = index.names.len() as u32;
            let mut span = ActorSpan {
                claim: a.claim.clone(),
                start,
                exact: HashMap::with_capacity(a.markers.len()),
                loose: HashMap::with_capacity(a.markers.len()),
            };
            for (k, m) in a.markers.iter().enumerate() {
                span.exact.entry(m.clone()).or_insert(k as u32);
                span.loose.entry(bare_name(m)).or_insert(k as u32);
            }
            index.names.extend(a.names.iter().cloned());
            index.actors.push(span);
        }
        index
    }

    /// Whether it resolves for several actors ([`Self::for_actors`]).
    pub fn is_for_actors(&self) -> bool {
        !self.actors.is_empty()
    }

    /// For a stage of several actors: the actor that claims `name` and the stage index
    /// of its marker, if it has one.
    fn claimed(&self, name: &str, scratch: &mut String) -> Result<Option<u32>, ()> {
        let subject = subject_of(name);
        let span = self
            .actors
            .iter()
            .find(|a| a.claim.claims(name, subject))
            .ok_or(())?;
        Ok(span.find(name, scratch))
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

    /// The index of `name`, if it matches (exactly, or loosely) a known marker, whatever
    /// its subject.
    pub fn get(&self, name: &str) -> Option<u32> {
        if self.is_for_actors() {
            return self.claimed(name, &mut String::new()).ok().flatten();
        }
        self.exact
            .get(name)
            .or_else(|| self.loose.get(&bare_name(name)))
            .copied()
    }

    /// [`Self::get`] without allocating once warm (the inputs call it per sample), for
    /// the subject this index takes: the first match of [`SubjectFilter::One`] takes its
    /// subject, and a match of any other is refused and counted. A
    /// growing index with room left also takes a new name (matched exactly only, so that
    /// `A` and `a` stay two markers of a stream).
    pub fn resolve(&mut self, name: &str) -> Option<u32> {
        if self.is_for_actors() {
            let mut scratch = std::mem::take(&mut self.scratch);
            let found = self.claimed(name, &mut scratch);
            self.scratch = scratch;
            return found.unwrap_or_else(|()| {
                self.refuse(subject_of(name));
                None
            });
        }
        let exact = self.exact.get(name).copied();
        let Some(max) = self.grow_up_to else {
            let k = match exact {
                Some(k) => k,
                None => {
                    bare_name_into(name, &mut self.scratch);
                    self.loose.get(&self.scratch).copied()?
                }
            };
            let subject = subject_of(name);
            if self.filter == SubjectFilter::All {
                // Every subject: only an exact name (`Bob:LFHD` is not `Ann:LFHD`).
                return exact;
            }
            return match &self.taken {
                Some(t) if t.eq_ignore_ascii_case(subject) => Some(k),
                Some(_) => {
                    self.refuse(subject);
                    None
                }
                None => {
                    self.taken = Some(subject.to_owned());
                    Some(k)
                }
            };
        };
        match exact {
            Some(k) => Some(k),
            None if self.names.len() < max && name.len() <= MAX_NAME_BYTES => {
                Some(self.insert(name))
            }
            None => None,
        }
    }

    /// Counts a sample of `subject` refused; the first of each subject is said once, as
    /// a warning (for the first [`MAX_OTHER_SUBJECTS`] subjects).
    fn refuse(&mut self, subject: &str) {
        self.refused += 1;
        let known = self.others.iter().any(|o| o.eq_ignore_ascii_case(subject));
        if !known && self.others.len() < MAX_OTHER_SUBJECTS && subject.len() <= MAX_NAME_BYTES {
            let whose = subjects_text(std::slice::from_ref(&subject.to_owned()));
            if self.is_for_actors() {
                tracing::warn!("labels of {whose} ignored: no actor claims them ([[actors]] subject or labels)");
            } else {
                tracing::warn!(
                    "labels of {whose} ignored: the character takes {} ([character] subject chooses)",
                    subject_text(self.taken.as_deref().unwrap_or_default())
                );
            }
            self.others.push(subject.to_owned());
        }
    }

    /// Every known name, by index.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The subject whose loose matches this index takes, once known.
    pub fn subject(&self) -> Option<&str> {
        self.taken.as_deref()
    }

    /// Samples refused as another subject's, and the first few such subjects.
    pub fn refused(&self) -> (u64, &[String]) {
        (self.refused, &self.others)
    }

    /// What a report says of the other subjects' samples, if any were refused:
    /// `"412 samples of subjects Bob, Cy ignored (the character takes Ann's)"`.
    pub fn refused_text(&self) -> Option<String> {
        if self.is_for_actors() {
            return (self.refused > 0).then(|| {
                format!(
                    "{} samples of {} ignored (no actor claims them)",
                    self.refused,
                    subjects_text(&self.others)
                )
            });
        }
        (self.refused > 0).then(|| {
            format!(
                "{} samples of {} ignored (the character takes {})",
                self.refused,
                subjects_text(&self.others),
                subject_text(self.taken.as_deref().unwrap_or_default())
            )
        })
    }
}

/// `subject "Bob"` or `subjects "Bob", (no prefix)`.
fn subjects_text(subjects: &[String]) -> String {
    let named: Vec<String> = subjects
        .iter()
        .map(|s| {
            if s.is_empty() {
                "(no prefix)".to_owned()
            } else {
                format!("{s:?}")
            }
        })
        .collect();
    match named.len() {
        1 => format!("subject {}", named[0]),
        _ => format!("subjects {}", named.join(", ")),
    }
}

/// `"Ann"'s labels`, or `the labels without a subject prefix`.
fn subject_text(subject: &str) -> String {
    if subject.is_empty() {
        "the labels without a subject prefix".to_owned()
    } else {
        format!("{subject:?}'s labels")
    }
}

/// The performers of a take for a character whose markers are `markers`: each subject
/// (`Ann` of `Ann:LFHD`; `""` for labels without a prefix) with at least `min_labels`
/// labels matching a marker, and how many, in the order first met. A prop's few markers,
/// or a model's outputs, are not a performer.
pub fn performers(
    labels: &[String],
    markers: &[String],
    min_labels: usize,
) -> Vec<(String, usize)> {
    let index = MarkerIndex::fixed(markers);
    let mut found: Vec<(String, usize)> = Vec::new();
    for l in labels.iter().filter(|l| index.get(l).is_some()) {
        let s = subject_of(l);
        match found.iter_mut().find(|(n, _)| n.eq_ignore_ascii_case(s)) {
            Some((_, c)) => *c += 1,
            None => found.push((s.to_owned(), 1)),
        }
    }
    found.retain(|(_, c)| *c >= min_labels);
    found
}

/// The markers of `index` no label feeds.
fn unfed(index: &MarkerIndex, marker_of_label: &[Option<u32>]) -> Vec<String> {
    index
        .names()
        .iter()
        .enumerate()
        .filter(|(k, _)| !marker_of_label.contains(&Some(*k as u32)))
        .map(|(_, m)| m.clone())
        .collect()
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
    /// The subject whose labels feed the markers (`""`: labels without a prefix), when
    /// any label matches.
    pub subject: Option<String>,
    /// The other subjects whose labels would match a marker, and those labels
    /// (ignored; not among [`Self::unmatched_labels`]).
    pub other_subjects: Vec<String>,
    pub other_subject_labels: Vec<String>,
}

impl LabelMap {
    /// Maps `labels` onto the markers of `index` ([`MarkerIndex::get`]), those of one
    /// subject: the one `index` is for, or else the one with most matching labels (the
    /// first of those tied).
    pub fn new(labels: &[String], index: &MarkerIndex) -> Self {
        fn loose<'l>(index: &MarkerIndex, l: &'l str) -> Option<&'l str> {
            index.get(l).map(|_| subject_of(l))
        }
        if index.is_for_actors() {
            return Self::for_actors(labels, index);
        }
        let subject: Option<String> = match &index.filter {
            SubjectFilter::Named(s) => Some(s.clone()),
            SubjectFilter::All => None,
            SubjectFilter::One => {
                let mut counts: Vec<(&str, usize)> = Vec::new();
                for s in labels.iter().filter_map(|l| loose(index, l)) {
                    match counts.iter_mut().find(|(n, _)| n.eq_ignore_ascii_case(s)) {
                        Some((_, c)) => *c += 1,
                        None => counts.push((s, 1)),
                    }
                }
                let most = counts.iter().map(|c| c.1).max().unwrap_or(0);
                counts.iter().find(|c| c.1 == most).map(|c| c.0.to_owned())
            }
        };
        let mut other_subjects: Vec<String> = Vec::new();
        let marker_of_label: Vec<Option<u32>> = labels
            .iter()
            .map(|l| match (loose(index, l), &subject) {
                (Some(s), Some(taken)) if !s.eq_ignore_ascii_case(taken) => {
                    if !other_subjects.iter().any(|o| o.eq_ignore_ascii_case(s)) {
                        other_subjects.push(s.to_owned());
                    }
                    None
                }
                _ => index.get(l),
            })
            .collect();
        let (other_subject_labels, unmatched_labels): (Vec<String>, Vec<String>) = labels
            .iter()
            .zip(&marker_of_label)
            .filter(|(_, m)| m.is_none())
            .map(|(l, _)| l.clone())
            .partition(|l| index.get(l).is_some());
        let unfed_markers = unfed(index, &marker_of_label);
        Self {
            marker_of_label,
            unmatched_labels,
            unfed_markers,
            subject,
            other_subjects,
            other_subject_labels,
        }
    }

    /// [`Self::new`] for an index of several actors: each label feeds the marker of the
    /// actor that claims it; the rest are unmatched.
    fn for_actors(labels: &[String], index: &MarkerIndex) -> Self {
        let marker_of_label: Vec<Option<u32>> = labels.iter().map(|l| index.get(l)).collect();
        let unmatched_labels = labels
            .iter()
            .zip(&marker_of_label)
            .filter(|(_, m)| m.is_none())
            .map(|(l, _)| l.clone())
            .collect();
        let unfed_markers = unfed(index, &marker_of_label);
        Self {
            marker_of_label,
            unmatched_labels,
            unfed_markers,
            subject: None,
            other_subjects: Vec::new(),
            other_subject_labels: Vec::new(),
        }
    }

    /// What a report says of the other subjects' labels, if any were ignored.
    pub fn others_text(&self) -> Option<String> {
        (!self.other_subjects.is_empty()).then(|| {
            format!(
                "{} labels of {} ignored (the character takes {}; [character] subject or `replay --subject` chooses)",
                self.other_subject_labels.len(),
                subjects_text(&self.other_subjects),
                subject_text(self.subject.as_deref().unwrap_or_default())
            )
        })
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
        let map = LabelMap::new(&names(&["Sub:WRIST", "C7", "Sub:index_nail"]), &index);
        assert_eq!(map.marker_of_label, vec![Some(0), None, Some(1)]);
        assert_eq!(map.unmatched_labels, names(&["C7"]));
        assert_eq!(map.unfed_markers, names(&["thumb_nail"]));
        // Vicon writes `Subject:LFHD`.
        let index = MarkerIndex::fixed(&names(&["C7", "LFHD", "RFHD", "T10"]));
        let map = LabelMap::new(
            &names(&["Subject:LFHD", "Subject:rfhd", "Subject:C7", "extra"]),
            &index,
        );
        assert_eq!(map.marker_of_label, vec![Some(1), Some(2), Some(0), None]);
        assert_eq!(map.unmatched_labels, names(&["extra"]));
        assert_eq!(map.unfed_markers, names(&["T10"]));
        assert_eq!(map.subject.as_deref(), Some("Subject"));
        assert_eq!(map.others_text(), None);
    }

    /// Two performers in one stream: the first subject matched takes the character,
    /// the other's samples are refused and counted, whatever their case or order.
    #[test]
    fn a_stream_of_two_subjects_feeds_one() {
        let mut index = MarkerIndex::fixed(&names(&["LFHD", "RFHD", "C7"]));
        assert_eq!(index.resolve("Ann:LFHD"), Some(0));
        assert_eq!(index.resolve("Bob:LFHD"), None);
        assert_eq!(index.resolve("Bob:RFHD"), None);
        assert_eq!(
            index.resolve("ann:rfhd"),
            Some(1),
            "a subject is named in any case"
        );
        assert_eq!(
            index.resolve("C7"),
            None,
            "no prefix is a subject of its own"
        );
        assert_eq!(index.subject(), Some("Ann"));
        let (refused, others) = index.refused();
        assert_eq!(refused, 3);
        assert_eq!(others, &names(&["Bob", ""])[..]);
        assert_eq!(
            index.refused_text().as_deref(),
            Some("3 samples of subjects \"Bob\", (no prefix) ignored (the character takes \"Ann\"'s labels)")
        );
        // Named: only that subject's, an exact name included.
        let mut bob = MarkerIndex::fixed_for(
            &names(&["LFHD", "RFHD"]),
            SubjectFilter::Named("Bob".into()),
        );
        assert_eq!(bob.resolve("LFHD"), None);
        assert_eq!(bob.resolve("Ann:LFHD"), None);
        assert_eq!(bob.resolve("Bob:LFHD"), Some(0));
        let mut bare =
            MarkerIndex::fixed_for(&names(&["LFHD"]), SubjectFilter::Named(String::new()));
        assert_eq!(bare.resolve("LFHD"), Some(0));
        assert_eq!(bare.resolve("Bob:LFHD"), None);
    }

    /// A recording of two subjects: the one with most matching labels feeds the
    /// markers, and the other is named.
    #[test]
    fn a_recording_of_two_subjects_maps_the_larger() {
        let index = MarkerIndex::fixed(&names(&["LFHD", "RFHD", "C7"]));
        let labels = names(&[
            "Ann:LFHD", "Ann:RFHD", "Bob:LFHD", "Bob:RFHD", "Bob:C7", "Box:C7",
        ]);
        let map = LabelMap::new(&labels, &index);
        assert_eq!(
            map.marker_of_label,
            vec![None, None, Some(0), Some(1), Some(2), None]
        );
        assert_eq!(map.subject.as_deref(), Some("Bob"));
        assert_eq!(map.other_subjects, names(&["Ann", "Box"]));
        assert_eq!(
            map.other_subject_labels,
            names(&["Ann:LFHD", "Ann:RFHD", "Box:C7"])
        );
        assert!(map.unmatched_labels.is_empty());
        assert!(map.others_text().unwrap().contains("\"Bob\"'s labels"));
        let ann = MarkerIndex::fixed_for(
            &names(&["LFHD", "RFHD", "C7"]),
            SubjectFilter::Named("ann".into()),
        );
        let map = LabelMap::new(&labels, &ann);
        assert_eq!(
            map.marker_of_label,
            vec![Some(0), Some(1), None, None, None, None]
        );
    }

    fn actor(subject: &str, claim: Claim, markers: &[&str]) -> ActorLabels {
        ActorLabels {
            names: markers.iter().map(|m| format!("{subject}:{m}")).collect(),
            markers: names(markers),
            claim,
        }
    }

    /// Several actors: each label goes to the actor whose claim takes it, found among
    /// that actor's markers alone; bare names never collide across actors; what no actor
    /// claims is refused and counted.
    #[test]
    fn several_actors_take_each_their_own_labels() {
        let body = ["LFHD", "RFHD", "C7"];
        let mut index = MarkerIndex::for_actors(&[
            actor("Ann", Claim::Subject("Ann".into()), &body),
            actor("Bob", Claim::Subject("Bob".into()), &body),
            actor("Cy", Claim::Patterns(vec!["cy_*".into()]), &body),
            actor("", Claim::Unprefixed, &["wrist"]),
        ]);
        assert_eq!(index.names().len(), 10);
        assert_eq!(index.resolve("Ann:LFHD"), Some(0));
        assert_eq!(index.resolve("BOB:lfhd"), Some(3), "Bob's LFHD, not Ann's");
        assert_eq!(index.resolve("Bob:C7"), Some(5));
        assert_eq!(index.resolve("CY_RFHD"), Some(7), "by the pattern's star");
        assert_eq!(index.resolve("wrist"), Some(9));
        assert_eq!(
            index.resolve("LFHD"),
            None,
            "unprefixed: only the wrist actor's"
        );
        assert_eq!(index.resolve("Ann:wrist"), None, "Ann has no wrist");
        assert_eq!(index.resolve("Dee:LFHD"), None);
        assert_eq!(index.resolve("Dee:RFHD"), None);
        // Claimed labels without a marker are not another subject's: only Dee counts.
        let (refused, others) = index.refused();
        assert_eq!((refused, others), (2, &names(&["Dee"])[..]));
        assert!(index
            .refused_text()
            .unwrap()
            .contains("no actor claims them"));
        let map = LabelMap::new(&names(&["Bob:RFHD", "Dee:C7", "Ann:C7"]), &index);
        assert_eq!(map.marker_of_label, vec![Some(4), None, Some(2)]);
        assert_eq!(map.unmatched_labels, names(&["Dee:C7"]));
        assert_eq!(map.unfed_markers.len(), 8);
    }

    #[test]
    fn the_performers_of_a_take_are_the_subjects_with_enough_markers() {
        let markers = names(&["LFHD", "RFHD", "C7", "T10"]);
        let labels = names(&[
            "Ann:LFHD",
            "Ann:RFHD",
            "Ann:C7",
            "Box:C7",
            "Bob:lfhd",
            "Bob:RFHD",
            "Bob:T10",
            "Bob:LKneeAngles",
        ]);
        assert_eq!(
            performers(&labels, &markers, 3),
            vec![("Ann".to_owned(), 3), ("Bob".to_owned(), 3)]
        );
        assert_eq!(performers(&labels, &markers, 4), vec![]);
    }

    #[test]
    fn patterns_match_any_case_with_stars_and_marks() {
        for (p, n, want) in [
            ("Ann_*", "ann_LFHD", true),
            ("Ann_*", "Ann", false),
            ("*:*HD", "Bob:LFHD", true),
            ("?FHD", "LFHD", true),
            ("?FHD", "LLFHD", false),
            ("a*b*c", "aXbYbZc", true),
            ("a*b*c", "aXbYbZ", false),
            ("*", "", true),
            ("", "x", false),
        ] {
            assert_eq!(glob_match(p, n), want, "{p} ~ {n}");
        }
    }

    proptest::proptest! {
        /// Over any stream of labels from a few subjects (in any case), no two subjects
        /// ever feed the index: every accepted sample's subject is the first accepted
        /// one's, and every refused match is counted.
        #[test]
        fn no_two_subjects_ever_feed_one_index(
            stream in proptest::collection::vec((0usize..4, 0usize..4, proptest::bool::ANY), 0..64)
        ) {
            let markers = names(&["LFHD", "RFHD", "C7"]);
            let mut index = MarkerIndex::fixed(&markers);
            let subjects = ["", "Ann", "Bob", "ANN"];
            let labels = ["LFHD", "rfhd", "C7", "T10"];
            let mut first: Option<String> = None;
            let mut refused = 0u64;
            for (s, l, _) in &stream {
                let label = if subjects[*s].is_empty() {
                    labels[*l].to_owned()
                } else {
                    format!("{}:{}", subjects[*s], labels[*l])
                };
                let matches = index.get(&label).is_some();
                match index.resolve(&label) {
                    Some(_) => {
                        let s = subjects[*s].to_ascii_lowercase();
                        let f = first.get_or_insert_with(|| s.clone());
                        proptest::prop_assert_eq!(&*f, &s);
                    }
                    None => refused += u64::from(matches),
                }
            }
            proptest::prop_assert_eq!(index.refused().0, refused);
        }

        /// Over any label (arbitrary text, or a subject and a marker name in any case),
        /// a stage index is within the span of the one actor whose subject the label
        /// carries: no sample ever crosses actors.
        #[test]
        fn no_label_ever_feeds_another_actor(
            picks in proptest::collection::vec((0usize..4, 0usize..4, proptest::bool::ANY), 0..64),
            junk in proptest::collection::vec(".{0,40}", 0..16),
        ) {
            let body = ["LFHD", "RFHD", "C7"];
            let mut index = MarkerIndex::for_actors(&[
                actor("Ann", Claim::Subject("Ann".into()), &body),
                actor("Bob", Claim::Subject("Bob".into()), &body),
                actor("", Claim::Unprefixed, &body),
            ]);
            let subjects = ["Ann", "bob", "", "Dee"];
            let labels = ["LFHD", "rfhd", "C7", "T10"];
            for (s, l, upper) in &picks {
                let mut label = if subjects[*s].is_empty() {
                    labels[*l].to_owned()
                } else {
                    format!("{}:{}", subjects[*s], labels[*l])
                };
                if *upper {
                    label = label.to_ascii_uppercase();
                }
                let span = match *s {
                    3 => None,
                    s => Some(3 * s as u32..3 * s as u32 + 3),
                };
                match index.resolve(&label) {
                    Some(k) => proptest::prop_assert!(span.is_some_and(|r| r.contains(&k)), "{label} -> {k}"),
                    None => proptest::prop_assert!(span.is_none() || *l == 3, "{label} lost"),
                }
            }
            for j in &junk {
                if let Some(k) = index.resolve(j) {
                    proptest::prop_assert!(k < 9);
                }
            }
        }
    }
}
