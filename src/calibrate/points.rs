//! Which of a take's points are markers on the actor's skin. A take holds more than
//! markers: model outputs a C3D stores as points (joint angles, forces, moments, powers,
//! centres of mass), a model's segment axes (Plug-in Gait's `PELO`, `PELA`, `PELL`,
//! `PELP`), unlabelled trajectories (Vicon's `*115`), another subject or a prop in the
//! volume, reference markers fixed in the room. Each rule here names what it excludes
//! and why, so the calibration can report it; the user's globs (`--exclude`,
//! `--include`) come first.
//!
//! Two passes: [`screen_by_name`] before a marker-set table is chosen (names, the file's
//! own word, points that never move), [`screen_by_geometry`] after (labels no table
//! knows that keep far from the body's known markers, or move as one rigid prop).

use super::labels::glob_match;
use super::marker_sets::normalise;
use glam::DVec3;

/// Why a point of the take is not taken as a marker on the actor.
#[derive(Clone, Debug, PartialEq)]
pub enum NotAMarker {
    /// The user's `--exclude` glob that matched.
    ByUser { glob: String },
    /// The file lists it under a model-output group (C3D POINT:ANGLES, FORCES, ...).
    ModelOutput { group: String },
    /// A trajectory the capture system left unlabelled (`*115`, `Unlabeled 3`).
    Unlabelled,
    /// One of a model's segment axes: four points `XO`, `XA`, `XL`, `XP` (origin,
    /// anterior, lateral, proximal) computed from the markers, inside the body.
    SegmentAxis { segment: String },
    /// Another subject's (`Subject:Label`; `""` for no prefix) than the one calibrated.
    OtherSubject { subject: String, kept: String },
    /// It never moves by more than [`CONSTANT_M`] while the body's markers do: fixed in
    /// the room, or a model output.
    Constant { moved_mm: f64 },
    /// No table knows it and it keeps farther from every known marker than the body's
    /// own spread allows.
    FarFromBody { distance_m: f64, limit_m: f64 },
    /// No table knows it and it moves rigidly with others as one object away from the
    /// body's known markers.
    Prop { with: usize, distance_m: f64 },
    /// The take gives this label to `points` points (`points` ≥ 2): which of them is the
    /// marker of that name cannot be told, and a layout names each marker once.
    Repeated { points: usize },
}

impl std::fmt::Display for NotAMarker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NotAMarker::ByUser { glob } => write!(f, "excluded by --exclude {glob:?}"),
            NotAMarker::ModelOutput { group } => {
                write!(f, "a model output the file lists under POINT:{group}, not a marker")
            }
            NotAMarker::Unlabelled => f.write_str("an unlabelled trajectory"),
            NotAMarker::SegmentAxis { .. } => f.write_str(
                "a segment's axis point (the segment's O, A, L and P are all in the take), computed by a model, not a marker",
            ),
            NotAMarker::OtherSubject { subject, kept } => write!(
                f,
                "subject {subject:?}, not {kept:?} (the one with most labels; --include \"{}\" takes it)",
                if subject.is_empty() { "LABEL".to_owned() } else { format!("{subject}:*") }
            ),
            NotAMarker::Constant { moved_mm } => write!(
                f,
                "moves {moved_mm:.2} mm at most while the body moves: fixed in the room or a model output"
            ),
            NotAMarker::FarFromBody {
                distance_m,
                limit_m,
            } => write!(
                f,
                "no table knows it and it keeps {distance_m:.2} m from the nearest known marker (over {limit_m:.2} m): not on the body"
            ),
            NotAMarker::Prop { with, distance_m } => write!(
                f,
                "moves rigidly with {with} other unknown labels as one object {distance_m:.2} m from the nearest known marker: a prop"
            ),
            NotAMarker::Repeated { points } => write!(
                f,
                "the take gives this label to {points} points: which is the marker cannot be told, and a layout names each marker once (give each point its own label in the take)"
            ),
        }
    }
}

/// The user's word on which labels are markers: globs (`*`, `?`, case-insensitive)
/// matched against the label as written and normalised.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointFilter {
    /// Labels to leave out.
    pub exclude: Vec<String>,
    /// Labels to take whatever the rules and `exclude` say (with `exclude = ["*"]`,
    /// the only labels taken).
    pub include: Vec<String>,
}

impl PointFilter {
    fn matching<'g>(globs: &'g [String], label: &str) -> Option<&'g String> {
        let norm = normalise(label);
        globs
            .iter()
            .find(|g| glob_match(g, label) || glob_match(g, &norm))
    }

    /// Whether the user's `--include` names `label` (then no rule excludes it).
    pub fn included(&self, label: &str) -> bool {
        Self::matching(&self.include, label).is_some()
    }
}

/// Largest movement of a point that counts as never moving, metres: an optical marker
/// on a body standing as still as it can sways by millimetres; a reference point or a
/// zero output column moves by nothing.
pub const CONSTANT_M: f64 = 1e-4;
/// Least movement of the body's markers for [`NotAMarker::Constant`] to apply, metres
/// (a take of a still mannequin says nothing of which points are fixed).
const BODY_MOVES_M: f64 = 0.01;

/// Fewest known markers the geometric rules measure against (as many as align a take
/// and a character: [`super::MIN_KNOWN_LABELS`]).
const MIN_KNOWN: usize = super::MIN_KNOWN_LABELS;

/// Frames the geometric rules compare (evenly spaced over the take).
const SAMPLED_FRAMES: usize = 200;

/// The label without its `Subject:` prefix, upper-cased.
fn bare(label: &str) -> String {
    label
        .rsplit(':')
        .next()
        .unwrap_or(label)
        .trim()
        .to_ascii_uppercase()
}

/// The subject of a `Subject:Label` label.
fn subject(label: &str) -> Option<&str> {
    label
        .rsplit_once(':')
        .map(|(s, _)| s.trim())
        .filter(|s| !s.is_empty())
}

/// Whether a label is a capture system's name for an unlabelled trajectory: empty,
/// `*` and digits (Vicon), or `Unlabeled`, `Unlabelled`, `Unidentified`, `Unnamed`
/// followed by anything (Motive, Qualisys and others).
fn is_unlabelled(label: &str) -> bool {
    let b = bare(label);
    if b.is_empty() {
        return true;
    }
    if let Some(rest) = b.strip_prefix('*') {
        return rest.chars().all(|c| c.is_ascii_digit());
    }
    ["UNLABELED", "UNLABELLED", "UNIDENTIFIED", "UNNAMED"]
        .iter()
        .any(|w| b.starts_with(w))
}

/// For each label, the segment whose axis points it is: labels `S` + `O`, `A`, `L`, `P`
/// all in the take (`S` at least three characters, the same subject).
fn segment_axes(labels: &[String]) -> Vec<Option<String>> {
    let keys: Vec<(Option<&str>, String)> = labels.iter().map(|l| (subject(l), bare(l))).collect();
    let has = |who: Option<&str>, name: &str| keys.iter().any(|(s, b)| *s == who && b == name);
    keys.iter()
        .map(|(who, b)| {
            let stem = b.strip_suffix(['O', 'A', 'L', 'P'])?;
            (stem.len() >= 3
                && stem.chars().all(|c| c.is_ascii_alphanumeric())
                && ["O", "A", "L", "P"]
                    .iter()
                    .all(|s| has(*who, &format!("{stem}{s}"))))
            .then(|| stem.to_owned())
        })
        .collect()
}

/// The first pass: for each label, why it is not a marker by its name, the file's
/// model-output groups (`point_groups[k]`, empty when the file says nothing) or the
/// user's filter; `None` for a label that may be a marker.
pub fn screen_by_name(
    labels: &[String],
    point_groups: &[Option<String>],
    filter: &PointFilter,
) -> Vec<Option<NotAMarker>> {
    let axes = segment_axes(labels);
    // The subject with most labels is the actor (labels without a `Subject:` prefix
    // count as one subject).
    let mut subjects: Vec<(Option<&str>, usize)> = Vec::new();
    for s in labels.iter().map(|l| subject(l)) {
        match subjects.iter_mut().find(|(n, _)| *n == s) {
            Some(e) => e.1 += 1,
            None => subjects.push((s, 1)),
        }
    }
    let kept_subject = subjects
        .iter()
        .max_by_key(|(_, n)| *n)
        .and_then(|(s, _)| *s);
    // A label given to several points: none of them is taken, whatever the filter says
    // (a layout written with the name twice is one the loader refuses).
    let mut uses: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
    for l in labels {
        *uses.entry(l.as_str()).or_default() += 1;
    }
    labels
        .iter()
        .enumerate()
        .map(|(k, label)| {
            let points = uses.get(label.as_str()).copied().unwrap_or(1);
            if points > 1 {
                return Some(NotAMarker::Repeated { points });
            }
            if filter.included(label) {
                return None;
            }
            if let Some(glob) = PointFilter::matching(&filter.exclude, label) {
                return Some(NotAMarker::ByUser { glob: glob.clone() });
            }
            if let Some(Some(group)) = point_groups.get(k) {
                return Some(NotAMarker::ModelOutput {
                    group: group.clone(),
                });
            }
            if is_unlabelled(label) {
                return Some(NotAMarker::Unlabelled);
            }
            if let Some(segment) = &axes[k] {
                return Some(NotAMarker::SegmentAxis {
                    segment: segment.clone(),
                });
            }
            let own = subject(label);
            if own != kept_subject {
                return Some(NotAMarker::OtherSubject {
                    subject: own.unwrap_or_default().to_owned(),
                    kept: kept_subject.unwrap_or_default().to_owned(),
                });
            }
            None
        })
        .collect()
}

/// Each label's largest distance from its first sample over the take (`None` with
/// fewer than two samples).
fn movements(frames: &[Vec<DVec3>], labels: usize) -> Vec<Option<f64>> {
    let mut first: Vec<Option<DVec3>> = vec![None; labels];
    let mut most: Vec<Option<f64>> = vec![None; labels];
    for f in frames {
        for (k, p) in f.iter().enumerate().take(labels) {
            if !p.is_finite() {
                continue;
            }
            match first[k] {
                None => first[k] = Some(*p),
                Some(a) => {
                    let d = (*p - a).length();
                    most[k] = Some(most[k].map_or(d, |m: f64| m.max(d)));
                }
            }
        }
    }
    most
}

/// The median of `v` (NaN when empty); reorders `v`.
fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    v.select_nth_unstable_by(mid, f64::total_cmp);
    v[mid]
}

/// The second pass, over labels no table, map or layout places (`unknown`), measured
/// against those that are placed (`known`), both as indices into `frames[f]`: a label
/// that never moves by more than [`CONSTANT_M`] while a known one moves by more than
/// [`BODY_MOVES_M`]; a label that keeps farther from every known marker than one and a
/// half times the body's spread (the median distance of its markers from their median
/// point: a skin marker lies within a segment's length of some known marker); and
/// groups of three or more that move as one rigid object (within `rigid_spread_m`)
/// whose middle keeps farther than the spread from every known marker, or farther than
/// half of it while the group is longer than three quarters of the spread (about
/// 0.35 m on an adult: a bat, a sword, a stick; a hand's, a foot's or a head's markers
/// span 0.1 to 0.25 m). Labels in `keep` are never excluded.
pub fn screen_by_geometry(
    frames: &[Vec<DVec3>],
    known: &[usize],
    unknown: &[usize],
    keep: &[bool],
    rigid_spread_m: f64,
) -> Vec<(usize, NotAMarker)> {
    // Fewer known markers than align a take say too little of where the body is.
    if known.len() < MIN_KNOWN || unknown.is_empty() || frames.is_empty() {
        return Vec::new();
    }
    let width = frames.iter().map(Vec::len).min().unwrap_or(0);
    if known.iter().chain(unknown).any(|&k| k >= width) {
        return Vec::new();
    }
    let moved = movements(frames, width);
    let body_moves = known
        .iter()
        .any(|&k| moved[k].is_some_and(|m| m > BODY_MOVES_M));
    let mut out = Vec::new();
    for &k in unknown.iter().filter(|&&k| !keep[k]) {
        match moved[k] {
            Some(m) if body_moves && m <= CONSTANT_M => {
                out.push((k, NotAMarker::Constant { moved_mm: m * 1e3 }))
            }
            _ => {}
        }
    }
    let unknown: Vec<usize> = unknown
        .iter()
        .copied()
        .filter(|k| out.iter().all(|(o, _)| o != k))
        .collect();
    let unknown = unknown.as_slice();
    let step = frames.len().div_ceil(SAMPLED_FRAMES).max(1);
    let sampled: Vec<&Vec<DVec3>> = frames.iter().step_by(step).collect();
    let spread = body_spread(&sampled, known, unknown);
    if !spread.is_finite() || spread <= 0.0 {
        return Vec::new();
    }
    let nearest_known = |p: DVec3, f: &[DVec3]| -> Option<f64> {
        known
            .iter()
            .map(|&j| f[j])
            .filter(|q| q.is_finite())
            .map(|q| (p - q).length())
            .min_by(f64::total_cmp)
    };
    let distance_of = |points: &[usize]| -> f64 {
        let mut d: Vec<f64> = sampled
            .iter()
            .filter_map(|f| {
                let seen: Vec<DVec3> = points
                    .iter()
                    .map(|&k| f[k])
                    .filter(|p| p.is_finite())
                    .collect();
                if seen.len() < points.len() {
                    return None;
                }
                let mid = seen.iter().sum::<DVec3>() / seen.len() as f64;
                nearest_known(mid, f)
            })
            .collect();
        median(&mut d)
    };
    // Props first (a bat's far end would otherwise go alone as far from the body).
    let rest: Vec<usize> = unknown.iter().copied().filter(|k| !keep[*k]).collect();
    let groups = rigid_groups(&sampled, &rest, rigid_spread_m);
    for g in 0..rest.len() {
        let members: Vec<usize> = (0..rest.len())
            .filter(|&i| groups[i] == g)
            .map(|i| rest[i])
            .collect();
        if members.len() < 3 {
            continue;
        }
        let d = distance_of(&members);
        let extent = extent_of(&sampled, &members);
        if d > spread || (d > 0.5 * spread && extent > 0.75 * spread) {
            for &k in &members {
                out.push((
                    k,
                    NotAMarker::Prop {
                        with: members.len() - 1,
                        distance_m: d,
                    },
                ));
            }
        }
    }
    let limit = 1.5 * spread;
    let singles: Vec<usize> = rest
        .iter()
        .copied()
        .filter(|k| out.iter().all(|(o, _)| o != k))
        .collect();
    for k in singles {
        let d = distance_of(&[k]);
        if d > limit {
            out.push((
                k,
                NotAMarker::FarFromBody {
                    distance_m: d,
                    limit_m: limit,
                },
            ));
        }
    }
    out.sort_by_key(|(k, _)| *k);
    out
}

/// The largest distance between two of `members` (median over the frames that see
/// them all).
fn extent_of(frames: &[&Vec<DVec3>], members: &[usize]) -> f64 {
    let mut per_frame: Vec<f64> = frames
        .iter()
        .filter(|f| members.iter().all(|&k| f[k].is_finite()))
        .map(|f| {
            let mut most = 0.0f64;
            for (i, &a) in members.iter().enumerate() {
                for &b in &members[i + 1..] {
                    most = most.max((f[a] - f[b]).length());
                }
            }
            most
        })
        .collect();
    median(&mut per_frame)
}

/// The body's spread: over the frames, the median distance of the labels (`known` and
/// `unknown`) from their component-wise median point; the median of that over frames.
fn body_spread(frames: &[&Vec<DVec3>], known: &[usize], unknown: &[usize]) -> f64 {
    let mut per_frame: Vec<f64> = frames
        .iter()
        .filter_map(|f| {
            let pts: Vec<DVec3> = known
                .iter()
                .chain(unknown)
                .map(|&k| f[k])
                .filter(|p| p.is_finite())
                .collect();
            if pts.len() < 3 {
                return None;
            }
            let axis = |a: fn(&DVec3) -> f64| median(&mut pts.iter().map(a).collect::<Vec<_>>());
            let mid = DVec3::new(axis(|p| p.x), axis(|p| p.y), axis(|p| p.z));
            Some(median(
                &mut pts.iter().map(|p| (*p - mid).length()).collect::<Vec<_>>(),
            ))
        })
        .collect();
    median(&mut per_frame)
}

/// Groups of `labels` (indices into `frames[f]`) that keep their mutual distances over
/// `frames` within `spread_m` RMS: each label's group number, the index in `labels` of
/// its group's root (labels never seen together three times are apart).
pub fn rigid_groups<F: AsRef<[DVec3]>>(
    frames: &[F],
    labels: &[usize],
    spread_m: f64,
) -> Vec<usize> {
    let n = labels.len();
    let mut group: Vec<usize> = (0..n).collect();
    fn root(g: &mut [usize], mut i: usize) -> usize {
        while g[i] != i {
            g[i] = g[g[i]];
            i = g[i];
        }
        i
    }
    for a in 0..n {
        for b in a + 1..n {
            let d: Vec<f64> = frames
                .iter()
                .filter_map(|f| {
                    let f = f.as_ref();
                    let (p, q) = (f[labels[a]], f[labels[b]]);
                    (p.is_finite() && q.is_finite()).then(|| (p - q).length())
                })
                .collect();
            if d.len() < 3 {
                continue;
            }
            let mean = d.iter().sum::<f64>() / d.len() as f64;
            let spread =
                (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / d.len() as f64).sqrt();
            if spread < spread_m {
                let (ra, rb) = (root(&mut group, a), root(&mut group, b));
                group[ra] = rb;
            }
        }
    }
    (0..n).map(|i| root(&mut group, i)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn labels(names: &[&str]) -> Vec<String> {
        names.iter().map(|s| s.to_string()).collect()
    }

    proptest! {
        /// Whatever the labels and the user's `--include` (which keeps a label against
        /// every other rule), a label given to several points is left out at each of
        /// them with their count, and every label kept is the take's only one of that
        /// name (so a layout never names a marker twice).
        #[test]
        fn a_repeated_label_is_never_kept(
            names in proptest::collection::vec("[A-Ca-c:_ ]{0,3}", 0..40),
            include_all in any::<bool>(),
        ) {
            let filter = PointFilter {
                include: if include_all { vec!["*".into()] } else { Vec::new() },
                ..PointFilter::default()
            };
            let got = screen_by_name(&names, &[], &filter);
            prop_assert_eq!(got.len(), names.len());
            for (label, why) in names.iter().zip(&got) {
                let n = names.iter().filter(|o| *o == label).count();
                if n > 1 {
                    prop_assert_eq!(why, &Some(NotAMarker::Repeated { points: n }));
                } else {
                    let repeated = matches!(why, Some(NotAMarker::Repeated { .. }));
                    prop_assert!(!repeated, "{:?}: {:?}", label, why);
                }
            }
        }
    }

    /// `n` labels over 10 frames, each moving along x by 5 cm a frame.
    fn moving(n: usize) -> Vec<Vec<DVec3>> {
        (0..10)
            .map(|f| {
                (0..n)
                    .map(|k| DVec3::new(0.05 * f as f64, 0.1 * k as f64, 0.0))
                    .collect()
            })
            .collect()
    }

    #[test]
    fn names_and_the_files_word_exclude_what_is_no_marker() {
        let l = labels(&[
            "LASI",
            "*115",
            "PELO",
            "PELA",
            "PELL",
            "PELP",
            "LHipAngles",
            "Unlabeled 3",
            "LFOO",
            "LFOA",
            "LFOL",
        ]);
        let mut groups = vec![None; l.len()];
        groups[6] = Some("ANGLES".to_owned());
        let got = screen_by_name(&l, &groups, &PointFilter::default());
        assert_eq!(got[0], None);
        assert_eq!(got[1], Some(NotAMarker::Unlabelled));
        for g in &got[2..6] {
            assert_eq!(
                *g,
                Some(NotAMarker::SegmentAxis {
                    segment: "PEL".into()
                })
            );
        }
        assert_eq!(
            got[6],
            Some(NotAMarker::ModelOutput {
                group: "ANGLES".into()
            })
        );
        assert_eq!(got[7], Some(NotAMarker::Unlabelled));
        // Three of the four axis points are no segment's axes.
        assert_eq!(&got[8..], &[None, None, None]);
    }

    #[test]
    fn the_users_globs_come_first_and_include_wins() {
        let l = labels(&["Bat1", "Bat2", "LASI", "*12"]);
        let filter = PointFilter {
            exclude: vec!["bat*".into()],
            include: vec![],
        };
        let got = screen_by_name(&l, &[], &filter);
        assert_eq!(
            got[0],
            Some(NotAMarker::ByUser {
                glob: "bat*".into()
            })
        );
        assert_eq!(got[2], None);
        let filter = PointFilter {
            exclude: vec!["*".into()],
            include: vec!["LASI".into(), "?12".into()],
        };
        let got = screen_by_name(&l, &[], &filter);
        assert_eq!(got[0], Some(NotAMarker::ByUser { glob: "*".into() }));
        assert_eq!(got[2], None, "included");
        assert_eq!(got[3], None, "an included unlabelled point is kept");
        // Include alone keeps what the rules would leave out, and leaves the rest be.
        let rescue = PointFilter {
            exclude: vec![],
            include: vec!["?12".into()],
        };
        let got = screen_by_name(&l, &[], &rescue);
        assert_eq!(got, vec![None, None, None, None]);
    }

    #[test]
    fn another_subject_and_fixed_points_are_left_out() {
        let l = labels(&["Box:a", "Ann:LASI", "Ann:RASI", "Ann:LPSI", "Ann:Floor"]);
        let got = screen_by_name(&l, &[], &PointFilter::default());
        // (Box:a is label 0; below, labels 0 to 3 are known and 4 never moves.)
        assert_eq!(
            got[0],
            Some(NotAMarker::OtherSubject {
                subject: "Box".into(),
                kept: "Ann".into()
            })
        );
        assert_eq!(&got[1..], &[None, None, None, None]);
        // Labels without a subject are one subject too.
        let l = labels(&["LASI", "RASI", "Other:LASI"]);
        let got = screen_by_name(&l, &[], &PointFilter::default());
        assert_eq!(&got[..2], &[None, None]);
        assert!(
            matches!(&got[2], Some(NotAMarker::OtherSubject { subject, .. }) if subject == "Other")
        );
        // A point that never moves while the body does; not in a still take, and not
        // when the user keeps it.
        let mut frames = moving(5);
        for f in &mut frames {
            f[4] = DVec3::new(1.0, 0.0, 1.0);
        }
        let keep = vec![false; 5];
        let got = screen_by_geometry(&frames, &[0, 1, 2, 3], &[4], &keep, 0.003);
        assert_eq!(got, vec![(4, NotAMarker::Constant { moved_mm: 0.0 })]);
        let still: Vec<Vec<DVec3>> = (0..10).map(|_| vec![DVec3::ONE; 5]).collect();
        assert!(screen_by_geometry(&still, &[0, 1, 2, 3], &[4], &keep, 0.003).is_empty());
        // Three known markers say too little of where the body is.
        assert!(screen_by_geometry(&frames, &[1, 2, 3], &[4], &keep, 0.003).is_empty());
        let kept = vec![true; 5];
        assert!(screen_by_geometry(&frames, &[0, 1, 2, 3], &[4], &kept, 0.003).is_empty());
    }

    /// A body of 8 known markers on a 1.6 m column walking along x, and unknown points:
    /// one on the body, one 3 m away, a bat held out from it, a rigid plate on the body.
    #[test]
    fn far_points_and_props_are_found_and_body_points_kept() {
        let frames: Vec<Vec<DVec3>> = (0..60)
            .map(|f| {
                let t = f as f64 * 0.05;
                let walk = DVec3::new(t, 0.0, 0.1 * (3.0 * t).sin());
                let mut v: Vec<DVec3> = (0..8)
                    .map(|k| walk + DVec3::new(0.1 * (k % 2) as f64, 0.2 * k as f64, 0.0))
                    .collect();
                // 8: on the body, moving on its own (a hand).
                v.push(walk + DVec3::new(0.3 * (2.0 * t).cos(), 1.0, 0.3 * (2.0 * t).sin()));
                // 9: far away.
                v.push(DVec3::new(3.0, 0.0, 3.0 + 0.1 * t));
                // 10..13: a bat held out from the body, turning: markers 0.3, 0.55
                // and 0.8 m along it.
                let q = glam::DQuat::from_rotation_y(0.5 * (2.0 * t).sin());
                for r in [0.3, 0.55, 0.8] {
                    v.push(walk + DVec3::new(0.0, 1.0, 0.0) + q * DVec3::new(0.0, 0.0, r));
                }
                // 13..16: a rigid plate strapped on the body (turning with nothing).
                for c in [DVec3::X, DVec3::Z, DVec3::NEG_X] {
                    v.push(walk + DVec3::new(0.05, 0.6, 0.05) + 0.03 * c);
                }
                v
            })
            .collect();
        let known: Vec<usize> = (0..8).collect();
        let unknown: Vec<usize> = (8..16).collect();
        let keep = vec![false; 16];
        let got = screen_by_geometry(&frames, &known, &unknown, &keep, 0.003);
        let excluded: Vec<usize> = got.iter().map(|(k, _)| *k).collect();
        assert_eq!(excluded, vec![9, 10, 11, 12], "{got:?}");
        assert!(matches!(got[0].1, NotAMarker::FarFromBody { .. }));
        assert!(matches!(got[1].1, NotAMarker::Prop { with: 2, .. }));
        // What the user keeps stays.
        let mut keep = keep;
        keep[9] = true;
        let got = screen_by_geometry(&frames, &known, &unknown, &keep, 0.003);
        assert!(got.iter().all(|(k, _)| *k != 9));
    }
}
