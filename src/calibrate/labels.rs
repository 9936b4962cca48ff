//! Which of the character's joints may carry each label of a take, and on whose word: the
//! character's own layout, the user's map (globs to joints or roles), a marker-set table
//! (a humanoid part per label, matched to joints by role), or nothing (any joint; the
//! solve picks the one the marker moves rigidly with).

use super::marker_sets::{best_set, candidate_joints, normalise, MarkerSet, Placed};
use super::points::NotAMarker;
use crate::character::roles::Role;
use crate::character::Character;
use glam::DVec3;

/// Where a label's bone came from.
#[derive(Clone, Debug, PartialEq)]
pub enum Source {
    /// The character's `[[markers]]` entry of that name.
    Layout,
    /// The user's map: the glob that matched.
    Map(String),
    /// A marker-set table: its name and the role it gives.
    Table { set: &'static str, role: Role },
    /// No one: the joint whose segments the marker moves with most rigidly.
    Motion,
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Source::Layout => f.write_str("layout"),
            Source::Map(glob) => write!(f, "map {glob:?}"),
            Source::Table { set, role } => write!(f, "{set}: {role}"),
            Source::Motion => f.write_str("motion"),
        }
    }
}

/// A label the calibration places.
#[derive(Clone, Debug)]
pub struct LabelPlan {
    /// Index in the take's labels.
    pub take_index: usize,
    pub label: String,
    pub source: Source,
    /// Joints that may carry it (one for the layout and a map naming a joint).
    pub candidates: Vec<usize>,
    /// Its rest position, when the layout gives one (metres, world frame).
    pub rest: Option<DVec3>,
    /// Where its marker set's manual puts it on the character's skin at rest, when the
    /// set's landmarks are known ([`super::landmarks`]; metres, world frame).
    pub template: Option<DVec3>,
}

/// Why a label is left out.
#[derive(Clone, Debug, PartialEq)]
pub enum LeftOut {
    /// The take never sees it.
    NoSamples,
    /// It is no marker on the actor (a model output, another subject, a prop...).
    NotAMarker(NotAMarker),
    /// The table says it is on a prop, not the body.
    Prop { set: &'static str },
    /// The table or map gives a role no joint of this character has.
    NoJointForRole { role: Role },
    /// The user's map names a role no joint of this character has.
    MapNamesNoJoint { target: String },
    /// The character has no joint with a bone to carry it.
    NoBones,
    /// Fitted farther outside the skin than a bind takes a marker (a marker on another
    /// person or a prop, or a take whose actor this character does not fit).
    TooFarOff { distance_mm: f64, limit_mm: f64 },
    /// Fitted farther from its bone's part of the control mesh than the bind takes (a
    /// take whose actor this character does not fit, or a label on the wrong bone).
    TooFarFromBone { distance_mm: f64, limit_mm: f64 },
}

impl std::fmt::Display for LeftOut {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LeftOut::NoSamples => f.write_str("no sample in the take"),
            LeftOut::NotAMarker(why) => write!(f, "{why}"),
            LeftOut::Prop { set } => write!(f, "{set} puts it on a prop, not the body"),
            LeftOut::NoJointForRole { role } => {
                write!(f, "no joint of the character has the role {role}")
            }
            LeftOut::MapNamesNoJoint { target } => {
                write!(
                    f,
                    "the map sends it to {target:?}, and no joint of the character is that"
                )
            }
            LeftOut::NoBones => f.write_str("the character has no bone to carry it"),
            LeftOut::TooFarOff {
                distance_mm,
                limit_mm,
            } => write!(
                f,
                "fitted {distance_mm:.0} mm off the skin, past the bind's {limit_mm:.0} mm"
            ),
            LeftOut::TooFarFromBone {
                distance_mm,
                limit_mm,
            } => write!(
                f,
                "fitted {distance_mm:.0} mm from its bone's part of the character, past the bind's {limit_mm:.0} mm"
            ),
        }
    }
}

/// A character file's `[calibration.bones]` (glob to joint or role) as map entries.
pub fn map_entries(map: &std::collections::BTreeMap<String, String>) -> Vec<MapEntry> {
    map.iter()
        .map(|(glob, target)| MapEntry {
            glob: glob.clone(),
            target: target.clone(),
        })
        .collect()
}

/// A user map entry: a glob over labels (`*` any run, `?` one character; compared
/// without case, against the label as written and normalised) and what it names.
#[derive(Clone, Debug, PartialEq)]
pub struct MapEntry {
    pub glob: String,
    /// A joint name of the skeleton, or a role (VRM humanoid name).
    pub target: String,
}

/// Why a user map entry cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("calibration.bones.{glob:?}: {target:?} is neither a joint of the character nor a role (VRM humanoid names such as \"leftHand\")")]
pub struct MapError {
    pub glob: String,
    pub target: String,
}

/// Whether `glob` matches `text` (ASCII case-insensitive; `*` and `?`).
pub fn glob_match(glob: &str, text: &str) -> bool {
    let g: Vec<char> = glob.chars().map(|c| c.to_ascii_uppercase()).collect();
    let t: Vec<char> = text.chars().map(|c| c.to_ascii_uppercase()).collect();
    // Iterative matching with one backtrack point (the last star).
    let (mut gi, mut ti) = (0, 0);
    let mut star: Option<(usize, usize)> = None;
    while ti < t.len() {
        if gi < g.len() && (g[gi] == '?' || g[gi] == t[ti]) {
            gi += 1;
            ti += 1;
        } else if gi < g.len() && g[gi] == '*' {
            star = Some((gi, ti));
            gi += 1;
        } else if let Some((sg, st)) = star {
            gi = sg + 1;
            ti = st + 1;
            star = Some((sg, st + 1));
        } else {
            return false;
        }
    }
    g[gi..].iter().all(|&c| c == '*')
}

/// The joints a map target names: a joint by name, else joints by role.
fn map_joints(
    ch: &Character,
    roles: &[Option<Role>],
    entry: &MapEntry,
) -> Result<Vec<usize>, MapError> {
    if let Some(j) = ch
        .skeleton
        .joints
        .iter()
        .position(|j| j.name == entry.target)
    {
        return Ok(vec![j]);
    }
    match entry.target.parse::<Role>() {
        Ok(role) => Ok(candidate_joints(role, roles)),
        Err(_) => Err(MapError {
            glob: entry.glob.clone(),
            target: entry.target.clone(),
        }),
    }
}

/// What the planning found.
#[derive(Clone, Debug)]
pub struct Plan {
    pub labels: Vec<LabelPlan>,
    pub left_out: Vec<(String, LeftOut)>,
    /// The table used and how many of the take's labels it knows.
    pub set: Option<(&'static MarkerSet, usize)>,
    /// Labels with samples that may be markers: what a table's share is counted of.
    pub markers: usize,
    /// The table that knows most labels when it knows too few of them to be used
    /// (under [`MIN_TABLE_SHARE`]), with how many it knows.
    pub declined: Option<(&'static MarkerSet, usize)>,
    /// A prefix every label shares (`L` of `LL_IAS`, `LR_FLE`) that the table lookups
    /// strip, because the table knows more labels without it.
    pub prefix: Option<String>,
}

/// Least share of a take's markers a table must know for its word to be taken when no
/// table is named: with fewer, the labels it happens to know (a `LWR` among 64 labels
/// of another set) are as likely another set's names.
pub const MIN_TABLE_SHARE: f64 = 0.5;

/// The longest prefix all `labels` share after [`normalise`] (none when it is empty or
/// a whole label).
fn common_prefix(labels: &[String]) -> Option<String> {
    let norm: Vec<String> = labels.iter().map(|l| normalise(l)).collect();
    let first = norm.first()?;
    let mut n = first.len();
    for l in &norm[1..] {
        n = n.min(
            first
                .bytes()
                .zip(l.bytes())
                .take_while(|(a, b)| a == b)
                .count(),
        );
    }
    (n > 0 && norm.iter().all(|l| l.len() > n)).then(|| first[..n].to_owned())
}

/// A table and how many labels it knows.
type Known = Option<(&'static MarkerSet, usize)>;
/// [`choose_table`]'s answer: the table used, the best one declined, the prefix
/// stripped.
type TableChoice = (Known, Known, Option<String>);

/// The table to use for `labels` (those that may be markers): the one named, or the
/// one that knows most when it knows at least [`MIN_TABLE_SHARE`] of them, tried as
/// written and with a shared prefix stripped. Returns the table and how many it knows,
/// the declined best, and the prefix stripped.
fn choose_table(labels: &[String], named: Option<&'static MarkerSet>) -> TableChoice {
    let prefix = common_prefix(labels);
    let stripped: Option<Vec<String>> = prefix.as_ref().map(|p| {
        labels
            .iter()
            .map(|l| normalise(l)[p.len()..].to_owned())
            .collect()
    });
    let count = |s: &'static MarkerSet| {
        let raw = s.known(labels);
        match &stripped {
            Some(st) if s.known(st) > raw => (s.known(st), true),
            _ => (raw, false),
        }
    };
    let (set, strip) = match named {
        Some(s) => {
            let (n, strip) = count(s);
            return (
                Some((s, n)),
                None,
                strip.then(|| prefix.unwrap_or_default()),
            );
        }
        None => {
            let raw = best_set(labels);
            let st = stripped.as_deref().and_then(best_set);
            match (raw, st) {
                (Some(r), Some(t)) if t.1 > r.1 => (Some(t), true),
                (None, Some(t)) => (Some(t), true),
                (r, _) => (r, false),
            }
        }
    };
    let enough = |n: usize| n as f64 >= MIN_TABLE_SHARE * labels.len() as f64;
    match set {
        Some((s, n)) if enough(n) => (
            Some((s, n)),
            None,
            strip.then(|| prefix.unwrap_or_default()),
        ),
        other => (None, other, None),
    }
}

/// Decides the candidate joints of every label of a take: the layout, then the map,
/// then the table (`set`, or the one that knows most labels when `None` and it knows
/// enough of them: [`choose_table`]), then any joint with children. `present[k]` is how
/// many frames have label `k`; labels `excluded` are no markers (the caller reports
/// them) and are skipped.
pub fn plan(
    ch: &Character,
    roles: &[Option<Role>],
    labels: &[String],
    present: &[usize],
    excluded: &[bool],
    map: &[MapEntry],
    set: Option<&'static MarkerSet>,
) -> Result<Plan, Vec<MapError>> {
    let mut errors = Vec::new();
    let mut map_targets = Vec::with_capacity(map.len());
    for e in map {
        match map_joints(ch, roles, e) {
            Ok(js) => map_targets.push(js),
            Err(err) => {
                errors.push(err);
                map_targets.push(Vec::new());
            }
        }
    }
    if !errors.is_empty() {
        return Err(errors);
    }
    let considered = |k: usize| !excluded.get(k).copied().unwrap_or(false) && present[k] > 0;
    let markers: Vec<String> = (0..labels.len())
        .filter(|&k| considered(k))
        .map(|k| labels[k].clone())
        .collect();
    let (set, declined, prefix) = choose_table(&markers, set);
    let table_label = |label: &str| match &prefix {
        Some(p) => normalise(label)
            .get(p.len()..)
            .unwrap_or_default()
            .to_owned(),
        None => label.to_owned(),
    };
    let any_joint: Vec<usize> = (0..ch.skeleton.len())
        .filter(|&j| ch.skeleton.children(j).next().is_some())
        .collect();
    let mut out = Plan {
        labels: Vec::new(),
        left_out: Vec::new(),
        set,
        markers: markers.len(),
        declined,
        prefix: prefix.clone(),
    };
    for (k, label) in labels.iter().enumerate() {
        if excluded.get(k).copied().unwrap_or(false) {
            continue;
        }
        if present[k] == 0 {
            out.left_out.push((label.clone(), LeftOut::NoSamples));
            continue;
        }
        let norm = normalise(label);
        let own = ch
            .markers
            .iter()
            .find(|m| m.name == *label || normalise(&m.name) == norm);
        let mapped = map
            .iter()
            .zip(&map_targets)
            .find(|(e, _)| glob_match(&e.glob, label) || glob_match(&e.glob, &norm));
        let (source, candidates, rest) = if let Some(m) = own {
            let c = m.joint.map_or_else(|| any_joint.clone(), |j| vec![j]);
            (Source::Layout, c, Some(m.rest))
        } else if let Some((e, js)) = mapped {
            (Source::Map(e.glob.clone()), js.clone(), None)
        } else if let Some(placed) =
            set.and_then(|(s, _)| s.place(&table_label(label)).map(|p| (s, p)))
        {
            match placed {
                (s, Placed::Prop) => {
                    out.left_out
                        .push((label.clone(), LeftOut::Prop { set: s.name }));
                    continue;
                }
                (s, Placed::Body(role)) => {
                    let js = candidate_joints(role, roles);
                    if js.is_empty() {
                        out.left_out
                            .push((label.clone(), LeftOut::NoJointForRole { role }));
                        continue;
                    }
                    (Source::Table { set: s.name, role }, js, None)
                }
            }
        } else {
            (Source::Motion, any_joint.clone(), None)
        };
        if candidates.is_empty() {
            let why = match &source {
                Source::Map(glob) => LeftOut::MapNamesNoJoint {
                    target: map
                        .iter()
                        .find(|e| &e.glob == glob)
                        .map_or_else(String::new, |e| e.target.clone()),
                },
                _ => LeftOut::NoBones,
            };
            out.left_out.push((label.clone(), why));
            continue;
        }
        out.labels.push(LabelPlan {
            take_index: k,
            label: label.clone(),
            source,
            candidates,
            rest,
            template: None,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn globs() {
        assert!(glob_match("L*WR*", "LWRA"));
        assert!(glob_match("l*wr*", "LWRB"));
        assert!(!glob_match("L*WR*", "RWRA"));
        assert!(glob_match("?FHD", "LFHD"));
        assert!(!glob_match("?FHD", "LLFHD"));
        assert!(glob_match("*", ""));
        assert!(glob_match("a*b*c", "aXXbYYc"));
        assert!(!glob_match("a*b*c", "aXXbYY"));
    }

    fn strings(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn a_table_is_used_only_when_it_knows_most_labels() {
        use crate::calibrate::marker_sets::by_name;
        // Plug-in Gait knows 4 of these 8 labels: half is enough.
        let half = strings(&["LASI", "RASI", "LPSI", "RPSI", "Q1", "Q2", "Q3", "Q4"]);
        let (set, declined, _) = choose_table(&half, None);
        assert_eq!(set.map(|(s, n)| (s.name, n)), Some(("plug-in-gait", 4)));
        assert!(declined.is_none());
        // One label fewer known: declined, and said.
        let fewer = strings(&["LASI", "RASI", "LPSI", "Q0", "Q1", "Q2", "Q3", "Q4"]);
        let (set, declined, _) = choose_table(&fewer, None);
        assert!(set.is_none());
        assert_eq!(
            declined.map(|(s, n)| (s.name, n)),
            Some(("plug-in-gait", 3))
        );
        // A table the user names is used whatever it knows.
        let named = by_name("plug-in-gait");
        assert_eq!(choose_table(&fewer, named).0.map(|(_, n)| n), Some(3));
    }

    #[test]
    fn a_prefix_every_label_shares_is_stripped_when_the_table_knows_more_without_it() {
        // A subject written without a colon before ISB labels.
        let labels = strings(&["LL_IAS", "LR_IAS", "LL_IPS", "LR_IPS", "LCV7", "LL_FLE"]);
        assert_eq!(common_prefix(&labels).as_deref(), Some("L"));
        let (set, _, prefix) = choose_table(&labels, None);
        let (set, n) = set.expect("a table");
        assert_eq!((set.name, n, prefix.as_deref()), ("isb", 6, Some("L")));
        // A left-side take keeps its labels as they are when the table knows them so.
        let left = strings(&["LASI", "LPSI", "LKNE", "LANK", "LTOE", "LHEE"]);
        let (set, _, prefix) = choose_table(&left, None);
        assert_eq!(set.map(|(s, n)| (s.name, n)), Some(("plug-in-gait", 6)));
        assert_eq!(prefix, None);
    }
}
