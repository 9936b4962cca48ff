//! The `[character]` table of a stage config: a procedural character or a character
//! file, with the section's own checks ([`CharacterConfig::problems`]).

use std::path::PathBuf;

/// `[character]`: exactly one of `procedural` or `path`.
#[derive(Clone, Debug, Default, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CharacterConfig {
    /// A procedural character: `"hand"` or `"body"`.
    pub procedural: Option<String>,
    /// A character file (TOML, see README), relative to the stage config's folder. It is
    /// baked on first use and its bake cache reused afterwards.
    pub path: Option<PathBuf>,
    /// Character metres per capture metre, applied to every incoming marker (a small
    /// actor driving a tall character); default: the character file's
    /// `calibration.marker_scale` (what `rigless calibrate --write` found), else 1.
    pub marker_scale: Option<f64>,
    /// Whose labels drive it when a stream or recording carries several performers'
    /// (`Subject:Label`, or a NatNet asset's `Asset:Marker`): `"Ann"` takes `Ann:*`,
    /// `""` the labels without a prefix. Default: one subject, the first whose label
    /// matches a marker in a stream, the one with most matching labels in a recording;
    /// the others' samples are ignored and counted.
    pub subject: Option<String>,
}

/// Longest `[character] subject` or actor name, bytes.
pub const MAX_SUBJECT_BYTES: usize = 256;

/// What is wrong with `s` as `what` (a subject or an actor's name), if anything.
pub fn name_problem(s: &str, what: &str) -> Option<String> {
    (s.contains(':') || s.trim() != s || s.len() > MAX_SUBJECT_BYTES).then(|| {
        format!("must be {what}, without `:` or surrounding spaces, at most {MAX_SUBJECT_BYTES} bytes; got {s:?}")
    })
}

/// The motions each procedural character plays (empty: no such character).
pub fn motions_of(procedural: &str) -> &'static [&'static str] {
    match procedural {
        "hand" => &["finger_play"],
        "body" => &["walk", "reach", "rom"],
        _ => &[],
    }
}

impl CharacterConfig {
    /// Whose labels feed its markers ([`Self::subject`]).
    pub fn subject_filter(&self) -> crate::markers::index::SubjectFilter {
        use crate::markers::index::SubjectFilter;
        self.subject
            .clone()
            .map_or(SubjectFilter::One, SubjectFilter::Named)
    }

    /// What is wrong, as `(key, message)` with keys relative to `[character]`.
    pub fn problems(&self) -> Vec<(String, String)> {
        let mut out = self.source_problems();
        if let Some(s) = &self.subject {
            if let Some(m) = name_problem(
                s,
                "a subject's name as it prefixes labels (`Ann` for `Ann:LFHD`)",
            ) {
                out.push(("subject".into(), m));
            }
        }
        if let Some(v) = self.marker_scale {
            use crate::character::file::{MAX_MARKER_SCALE, MIN_MARKER_SCALE};
            if !(v.is_finite() && (MIN_MARKER_SCALE..=MAX_MARKER_SCALE).contains(&v)) {
                out.push((
                    "marker_scale".into(),
                    format!("must be {MIN_MARKER_SCALE} to {MAX_MARKER_SCALE} (character metres per capture metre), got {v:?}"),
                ));
            }
        }
        out
    }

    /// What is wrong with the choice of character.
    fn source_problems(&self) -> Vec<(String, String)> {
        match (&self.procedural, &self.path) {
            (Some(_), Some(_)) => vec![(
                String::new(),
                "give either procedural or path, not both".into(),
            )],
            (None, None) => vec![(
                String::new(),
                "missing: set procedural = \"hand\" or \"body\", or path = \"CHARACTER.toml\""
                    .into(),
            )],
            (Some(p), None) if motions_of(p).is_empty() => vec![(
                "procedural".into(),
                format!("unknown procedural character {p:?} (expected \"hand\" or \"body\")"),
            )],
            _ => Vec::new(),
        }
    }
}
