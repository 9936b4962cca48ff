//! The stage config (`rigless run --config stage.toml`): which character (or which
//! `[[actors]]`, [`ActorConfig`]: one per performer), which inputs,
//! how the solver runs, where the outputs go, what is recorded. Each section's struct
//! belongs to the component it configures (its keys documented there, unknown keys
//! refused, its own checks); this module reads the file, hands each section to its
//! struct, adds the rules that span sections, and reports every problem at once with its
//! line.
//!
//! ```toml
//! [character]
//! procedural = "hand"            # or: path = "hand/hand.toml" (a character file)
//!
//! [solver]
//! rate_hz = 120
//!
//! [[inputs]]
//! type = "synthetic"             # the in-process test source
//! motion = "finger_play"
//!
//! [outputs.stream]
//! tcp = "127.0.0.1:7878"
//! ```

use crate::calibrate::config::LiveCalibrationConfig;
use crate::character::config::{motions_of, name_problem, CharacterConfig, MAX_SUBJECT_BYTES};
use crate::input::config::InputConfig;
use crate::markers::buffer::BufferConfig;
use crate::output::config::OutputsConfig;
use crate::replay::config::RecorderConfig;
use crate::runtime::files::{read_text_bounded, MAX_TEXT_BYTES};
use crate::runtime::toml_doc::{in_file_order, syntax_error, typed, Lines};
use crate::solve::config::SolverConfig;

/// A whole stage config.
#[derive(Clone, Debug, PartialEq)]
pub struct StageConfig {
    /// `[character]`: the one performer of a stage without `[[actors]]`.
    pub character: CharacterConfig,
    /// `[[actors]]`: the performers of a stage of several (empty: `[character]`).
    pub actors: Vec<ActorConfig>,
    /// `[solver]`.
    pub solver: SolverConfig,
    /// `[buffer]`: gap filling and gating.
    pub buffer: BufferConfig,
    /// `[[inputs]]`.
    pub inputs: Vec<InputConfig>,
    /// `[outputs]`.
    pub outputs: OutputsConfig,
    /// `[recorder]`.
    pub recorder: RecorderConfig,
    /// `[calibration]`: the marker layout from the first seconds of live input.
    pub calibration: LiveCalibrationConfig,
}

/// Why a stage config was refused: every problem, each with its line when known.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: {} problem{}:\n  - {}", .problems.len(), if .problems.len() == 1 { "" } else { "s" }, .problems.join("\n  - "))]
    Invalid { path: String, problems: Vec<String> },
}

/// Most `labels` patterns of an actor.
const MAX_PATTERNS: usize = 64;

/// One `[[actors]]` entry: a performer on a stage of several, its character and how its
/// labels are recognised among the others'.
#[derive(Clone, Debug, Default, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActorConfig {
    /// The actor's name, unique on the stage: status lines, summaries and outputs name
    /// it.
    pub name: String,
    /// A procedural character: `"hand"` or `"body"`.
    pub procedural: Option<String>,
    /// A character file, relative to the stage config's folder.
    pub path: Option<std::path::PathBuf>,
    /// Character metres per capture metre, as in `[character]`.
    pub marker_scale: Option<f64>,
    /// Its labels are this subject's (`"Ann"` takes `Ann:*` from C3D and TSV files, the
    /// NatNet asset `Ann`, the VRPN tracker `Ann`, OSC `/…/Ann/{name}` addresses).
    pub subject: Option<String>,
    /// Or: its labels are those matching any of these patterns (`*` any run, `?` one
    /// character, any case; `"Ann_*"` finds `LFHD` in `Ann_LFHD`). Neither `subject`
    /// nor `labels`: the labels without a subject prefix.
    pub labels: Option<Vec<String>>,
    /// Its deformation method (default: `[solver] method`).
    pub method: Option<crate::solve::frame::Method>,
}

impl ActorConfig {
    /// Its character, as a `[character]` table would give it.
    pub fn character(&self) -> CharacterConfig {
        CharacterConfig {
            procedural: self.procedural.clone(),
            path: self.path.clone(),
            marker_scale: self.marker_scale,
            subject: None,
        }
    }

    /// How it claims its labels.
    pub fn claim(&self) -> crate::markers::index::Claim {
        use crate::markers::index::Claim;
        match (&self.subject, &self.labels) {
            (Some(s), _) => Claim::Subject(s.clone()),
            (None, Some(p)) => Claim::Patterns(p.clone()),
            (None, None) => Claim::Unprefixed,
        }
    }

    /// What is wrong, as `(key, message)` with keys relative to the entry.
    pub fn problems(&self) -> Vec<(String, String)> {
        let mut out = self.character().problems();
        if let Some(m) = name_problem(&self.name, "a name for the actor") {
            out.push(("name".into(), m));
        } else if self.name.is_empty() {
            out.push(("name".into(), "missing: every actor needs a name".into()));
        }
        if let Some(s) = &self.subject {
            if let Some(m) = name_problem(
                s,
                "a subject's name as it prefixes labels (`Ann` for `Ann:LFHD`)",
            ) {
                out.push(("subject".into(), m));
            }
        }
        match (&self.subject, &self.labels) {
            (Some(_), Some(_)) => out.push((
                "labels".into(),
                "give either subject or labels, not both".into(),
            )),
            (None, Some(p))
                if p.is_empty()
                    || p.len() > MAX_PATTERNS
                    || p.iter()
                        .any(|p| p.is_empty() || p.len() > MAX_SUBJECT_BYTES) =>
            {
                out.push((
                    "labels".into(),
                    format!("must be 1 to {MAX_PATTERNS} non-empty patterns of at most {MAX_SUBJECT_BYTES} bytes"),
                ));
            }
            _ => {}
        }
        out
    }
}

/// Whether two actors' claims surely take some of the same labels: the same subject, both
/// the unprefixed labels, or a pattern of one that takes a label of the other's (tried on
/// a few marker names).
pub fn claims_overlap(a: &crate::markers::index::Claim, b: &crate::markers::index::Claim) -> bool {
    use crate::markers::index::Claim;
    const PROBES: [&str; 4] = ["LFHD", "C7", "wrist", "x"];
    let probes = |c: &Claim| -> Vec<String> {
        match c {
            Claim::Subject(s) => PROBES.iter().map(|m| format!("{s}:{m}")).collect(),
            Claim::Unprefixed => PROBES.iter().map(|m| m.to_string()).collect(),
            Claim::Patterns(ps) => ps
                .iter()
                .flat_map(|p| {
                    PROBES
                        .iter()
                        .map(move |m| p.replacen('*', m, 1).replace(['*', '?'], "x"))
                })
                .collect(),
        }
    };
    let takes = |c: &Claim, label: &str| c.claims(label, crate::markers::index::subject_of(label));
    probes(a).iter().any(|l| takes(b, l)) || probes(b).iter().any(|l| takes(a, l))
}

/// The sections a stage config may have.
const SECTIONS: [&str; 8] = [
    "character",
    "actors",
    "solver",
    "buffer",
    "inputs",
    "outputs",
    "recorder",
    "calibration",
];

fn section<T: serde::de::DeserializeOwned + Default>(
    table: &toml::Table,
    key: &str,
    lines: &Lines,
    problems: &mut Vec<String>,
) -> T {
    table
        .get(key)
        .and_then(|v| typed(v, key, lines, problems))
        .unwrap_or_default()
}

/// Problems of one section, `(key relative to the section, message)`, at their lines.
fn add_problems(
    section: &str,
    found: Vec<(String, String)>,
    lines: &Lines,
    problems: &mut Vec<String>,
) {
    for (key, message) in found {
        let path = if key.is_empty() {
            section.to_owned()
        } else {
            format!("{section}.{key}")
        };
        problems.push(lines.at(&path, message));
    }
}

/// An array of tables (`[[inputs]]`, `[[actors]]`), each entry typed (problems of
/// shape reported).
fn array_of<T: serde::de::DeserializeOwned>(
    table: &toml::Table,
    key: &str,
    lines: &Lines,
    problems: &mut Vec<String>,
) -> Vec<T> {
    match table.get(key) {
        None => Vec::new(),
        Some(toml::Value::Array(a)) => a
            .iter()
            .enumerate()
            .filter_map(|(i, v)| typed::<T>(v, &format!("{key}[{i}]"), lines, problems))
            .collect(),
        Some(_) => {
            problems.push(lines.at(key, format!("must be an array of tables ([[{key}]])")));
            Vec::new()
        }
    }
}

/// One performer of a stage, as the stage runs it: `[character]` or an `[[actors]]`
/// entry.
#[derive(Clone, Debug, PartialEq)]
pub struct ActorSpec {
    /// Its name (`None`: the one `[character]`, named by its character).
    pub name: Option<String>,
    pub character: CharacterConfig,
    /// How its labels are recognised among several actors' (`None`: the one
    /// `[character]`, which takes one subject's, [`CharacterConfig::subject`]).
    pub claim: Option<crate::markers::index::Claim>,
    pub method: crate::solve::frame::Method,
}

impl StageConfig {
    /// The stage's performers, in the config's order.
    pub fn actor_specs(&self) -> Vec<ActorSpec> {
        if self.actors.is_empty() {
            return vec![ActorSpec {
                name: None,
                character: self.character.clone(),
                claim: None,
                method: self.solver.method,
            }];
        }
        self.actors
            .iter()
            .map(|a| ActorSpec {
                name: Some(a.name.clone()),
                character: a.character(),
                claim: Some(a.claim()),
                method: a.method.unwrap_or(self.solver.method),
            })
            .collect()
    }

    /// The procedural character a synthetic input plays: `[character]`'s, or the first
    /// actor's.
    pub fn first_procedural(&self) -> Option<&String> {
        match self.actors.first() {
            Some(a) => a.procedural.as_ref(),
            None => self.character.procedural.as_ref(),
        }
    }
}

/// The most actors a stage drives (the vertex stream carries an actor's index in a byte;
/// past a few dozen, no machine solves them all at a capture rate anyway).
pub const MAX_ACTORS: usize = 64;

/// The `[[actors]]` rules: not with `[character]`, names unique, no two claiming the
/// same labels, each entry's own problems; and what a stage of several cannot do yet.
fn actors_problems(
    c: &StageConfig,
    table: &toml::Table,
    lines: &Lines,
    problems: &mut Vec<String>,
) {
    if c.actors.is_empty() {
        add_problems("character", c.character.problems(), lines, problems);
        return;
    }
    if table.contains_key("character") {
        problems.push(lines.at(
            "character",
            "give either [character] (one performer) or [[actors]], not both",
        ));
    }
    if c.actors.len() > MAX_ACTORS {
        problems.push(lines.at(
            "actors",
            format!(
                "{} actors: a stage drives at most {MAX_ACTORS} (the vertex stream tags each frame with its actor's index in one byte)",
                c.actors.len()
            ),
        ));
    }
    for (i, a) in c.actors.iter().enumerate() {
        let at = format!("actors[{i}]");
        add_problems(&at, a.problems(), lines, problems);
        let earlier = &c.actors[..i];
        if let Some(j) = earlier.iter().position(|b| b.name == a.name) {
            problems.push(lines.at(
                &format!("{at}.name"),
                format!("actor {:?} is named twice (first as actors[{j}])", a.name),
            ));
        }
        if let Some(j) = earlier
            .iter()
            .position(|b| claims_overlap(&b.claim(), &a.claim()))
        {
            problems.push(lines.at(
                &at,
                format!(
                    "actor {:?} claims labels actor {:?} (actors[{j}]) claims: {} and {}; give each its own subject or labels",
                    a.name,
                    c.actors[j].name,
                    a.claim().describe(),
                    c.actors[j].claim().describe()
                ),
            ));
        }
    }
    if c.calibration.write {
        for (i, a) in c.actors.iter().enumerate() {
            let at = format!("actors[{i}]");
            if a.path.is_none() {
                problems.push(lines.at(
                    &at,
                    format!("calibration.write writes each actor's layout into its character file; actor {:?} has none (a procedural character)", a.name),
                ));
            } else if let Some(j) = c.actors[..i].iter().position(|b| b.path == a.path) {
                problems.push(lines.at(
                    &at,
                    format!("calibration.write: actors {:?} and {:?} share one character file, and each performer's layout is its own; give each a copy of the file", c.actors[j].name, a.name),
                ));
            }
        }
    }
}

/// The rules that span sections: a synthetic input plays the procedural character's
/// motions, and a stage needs an input.
fn cross_section_problems(c: &StageConfig, lines: &Lines, problems: &mut Vec<String>) {
    for (i, input) in c.inputs.iter().enumerate() {
        let InputConfig::Synthetic(s) = input else {
            continue;
        };
        let at = format!("inputs[{i}]");
        match c.first_procedural() {
            None => problems.push(lines.at(
                &at,
                "a synthetic input needs a procedural character (character.procedural, or the first actor's procedural)",
            )),
            Some(ch) => {
                let ok = motions_of(ch);
                if let Some(m) = s
                    .motion
                    .as_ref()
                    .filter(|m| !ok.is_empty() && !ok.contains(&m.as_str()))
                {
                    problems.push(lines.at(
                        &format!("{at}.motion"),
                        format!("the {ch} has no motion {m:?} (it has {ok:?})"),
                    ));
                }
            }
        }
    }
    if c.inputs.is_empty() {
        problems.push(lines.at("inputs", "no inputs: add at least one [[inputs]] table"));
    }
    if c.calibration.write && c.character.path.is_none() && c.actors.is_empty() {
        problems.push(lines.at(
            "calibration.write",
            "writing the layout needs a character file (character.path); a procedural character has none (`rigless export-character hand|body DIR` writes one)",
        ));
    }
}

/// Parses and validates a stage config's text; `path` names it in errors. Relative
/// paths are kept as written (resolve them against the file's folder).
pub fn parse_stage(text: &str, path: &str) -> Result<StageConfig, ConfigError> {
    let invalid = |problems: Vec<String>| ConfigError::Invalid {
        path: path.to_owned(),
        problems,
    };
    let table: toml::Table =
        toml::from_str(text).map_err(|e| invalid(vec![syntax_error(text, &e)]))?;
    let lines = Lines::scan(text);
    let mut problems = Vec::new();
    for k in table.keys().filter(|k| !SECTIONS.contains(&k.as_str())) {
        problems.push(lines.at(
            k,
            format!("unknown section (expected {})", SECTIONS.join(", ")),
        ));
    }
    let config = StageConfig {
        character: section(&table, "character", &lines, &mut problems),
        actors: array_of(&table, "actors", &lines, &mut problems),
        solver: section(&table, "solver", &lines, &mut problems),
        buffer: section(&table, "buffer", &lines, &mut problems),
        inputs: array_of(&table, "inputs", &lines, &mut problems),
        outputs: section(&table, "outputs", &lines, &mut problems),
        recorder: section(&table, "recorder", &lines, &mut problems),
        calibration: section(&table, "calibration", &lines, &mut problems),
    };
    actors_problems(&config, &table, &lines, &mut problems);
    add_problems("solver", config.solver.problems(), &lines, &mut problems);
    add_problems("buffer", config.buffer.problems(), &lines, &mut problems);
    add_problems("outputs", config.outputs.problems(), &lines, &mut problems);
    add_problems(
        "recorder",
        config.recorder.problems(),
        &lines,
        &mut problems,
    );
    add_problems(
        "calibration",
        config.calibration.problems(),
        &lines,
        &mut problems,
    );
    for (i, input) in config.inputs.iter().enumerate() {
        add_problems(
            &format!("inputs[{i}]"),
            input.problems(),
            &lines,
            &mut problems,
        );
    }
    cross_section_problems(&config, &lines, &mut problems);
    if problems.is_empty() {
        return Ok(config);
    }
    in_file_order(&mut problems);
    Err(invalid(problems))
}

/// Reads and parses a stage config file.
pub fn load_stage(path: &std::path::Path) -> Result<StageConfig, ConfigError> {
    let shown = path.display().to_string();
    let text = read_text_bounded(path, MAX_TEXT_BYTES).map_err(|source| ConfigError::Read {
        path: shown.clone(),
        source,
    })?;
    parse_stage(&text, &shown)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::config::SolverConfig;

    const GOOD: &str = r#"
[character]
procedural = "body"

[solver]
rate_hz = 90

[buffer]
predict_max_gap_secs = 0.2

[[inputs]]
type = "synthetic"
motion = "reach"
loop = true

[outputs.stream]
tcp = "127.0.0.1:0"
"#;

    #[test]
    fn a_good_config_reads_with_defaults_filled_in() {
        let c = parse_stage(GOOD, "stage.toml").unwrap();
        assert_eq!(c.character.procedural.as_deref(), Some("body"));
        assert_eq!(c.solver.rate_hz, 90.0);
        assert_eq!(c.solver.max_iterations, 30);
        assert_eq!(c.buffer.predict_max_gap_secs, 0.2);
        assert_eq!(c.buffer.history_len, BufferConfig::default().history_len);
        let InputConfig::Synthetic(s) = &c.inputs[0] else {
            panic!("{:?}", c.inputs[0])
        };
        assert_eq!(s.motion.as_deref(), Some("reach"));
        assert!(s.looping);
        assert_eq!(c.outputs.stream.tcp, Some("127.0.0.1:0".parse().unwrap()));
    }

    #[test]
    fn every_problem_is_reported_at_once_with_its_line() {
        let bad = r#"
[character]
procedural = "body"

[solver]
rate_hz = -5
max_iterations = 0
colour = "red"

[buffer]
bogus = 1

[[inputs]]
type = "synthetic"
motion = "finger_play"
gap_percent = 95

[lights]
on = true
"#;
        let err = parse_stage(bad, "stage.toml").unwrap_err();
        let ConfigError::Invalid { problems, .. } = &err else {
            panic!("{err}")
        };
        let text = problems.join("\n");
        assert_eq!(problems.len(), 7, "{text}");
        for want in [
            "line 6: solver.rate_hz",
            "line 7: solver.max_iterations",
            "line 8: solver.colour: unknown field",
            "line 11: buffer.bogus: unknown field",
            "line 15: inputs[0].motion",
            "line 16: inputs[0].gap_percent",
            "line 18: lights: unknown section",
        ] {
            assert!(text.contains(want), "missing {want:?} in:\n{text}");
        }
    }

    #[test]
    fn a_synthetic_session_is_bounded() {
        // session_secs 1e300 made the session (all of it, before playing) until memory
        // ran out.
        let cfg = |secs: &str, rate: &str| {
            format!("[character]\nprocedural = \"hand\"\n[[inputs]]\ntype = \"synthetic\"\nsession_secs = {secs}\nrate_hz = {rate}\n")
        };
        let e = parse_stage(&cfg("1e300", "120"), "s.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("session_secs") && e.contains("(0, 3600] s, got 1e300"),
            "{e}"
        );
        let e = parse_stage(&cfg("3600", "1000"), "s.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("3600 s at 1000 Hz is more than a million frames"),
            "{e}"
        );
        parse_stage(&cfg("600", "120"), "s.toml").unwrap();
    }

    #[test]
    fn replay_inputs_name_a_bundled_session_or_a_file() {
        let ok = "[character]\nprocedural = \"hand\"\n[[inputs]]\ntype = \"replay\"\nsession = \"hand_finger_play\"\nspeed = 2\n";
        let c = parse_stage(ok, "s.toml").unwrap();
        let InputConfig::Replay(r) = &c.inputs[0] else {
            panic!("{:?}", c.inputs[0])
        };
        assert_eq!(
            (r.session.as_deref(), r.speed, r.looping),
            (Some("hand_finger_play"), 2.0, false)
        );
        let bad = "[character]\npath = \"x.toml\"\n[[inputs]]\ntype = \"replay\"\nsession = \"nope\"\n[[inputs]]\ntype = \"replay\"\nspeed = 0\n";
        let text = parse_stage(bad, "s.toml").unwrap_err().to_string();
        for want in [
            "line 5: inputs[0].session: no bundled session \"nope\"",
            "line 6: inputs[1]: a replay input needs session",
            "line 8: inputs[1].speed: must be in (0, 100]",
        ] {
            assert!(text.contains(want), "missing {want:?} in {text}");
        }
    }

    #[test]
    fn the_shipped_stage_files_are_valid_and_show_the_defaults() {
        let hand = parse_stage(include_str!("../stages/hand.toml"), "stages/hand.toml").unwrap();
        // stages/hand.toml spells out every default (except its looping input).
        assert_eq!(hand.solver, SolverConfig::default());
        assert_eq!(hand.buffer, BufferConfig::default());
        parse_stage(
            include_str!("../stages/body-walk.toml"),
            "stages/body-walk.toml",
        )
        .unwrap();
        let two = parse_stage(
            include_str!("../stages/two-actors.toml"),
            "stages/two-actors.toml",
        )
        .unwrap();
        assert_eq!(two.actor_specs().len(), 2);
        let glove = parse_stage(
            include_str!("../stages/hand-glove.toml"),
            "stages/hand-glove.toml",
        )
        .unwrap();
        let InputConfig::Glove(g) = &glove.inputs[0] else {
            panic!("{:?}", glove.inputs[0]);
        };
        let cal = g.calibration(4095);
        assert_eq!((cal[1].open, cal[1].closed), (250, 3800));
        assert_eq!(g.joints()[4], ["pinky_1", "pinky_2", "pinky_3"]);
    }

    #[test]
    fn glove_inputs_name_fingers_and_take_glove_urls() {
        let err = parse_stage(
            "[character]\nprocedural = \"hand\"\n[[inputs]]\ntype = \"glove\"\nurl = \"osc://127.0.0.1:9\"\ncalibration.thumbs = { open = 0, closed = 9 }\n",
            "s.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("is not a glove:// URL"), "{err}");
        assert!(err.contains("\"thumbs\" is not a finger"), "{err}");
    }

    #[test]
    fn the_solver_method_is_chosen_in_the_stage() {
        let stage = "[character]\nprocedural = \"hand\"\n[solver]\nmethod = \"harmonic\"\nharmonic_margin = 0.1\n[[inputs]]\ntype = \"synthetic\"\n";
        let cfg = parse_stage(stage, "s.toml").unwrap();
        let params = cfg.solver.params();
        assert_eq!(params.method, crate::solve::frame::Method::Harmonic);
        assert_eq!(params.harmonic.margin, 0.1);
        let bad = stage.replace("0.1", "0.7");
        let err = parse_stage(&bad, "s.toml").unwrap_err().to_string();
        assert!(
            err.contains("line 5: solver.harmonic_margin: must be in [0, 0.5)"),
            "{err}"
        );
        let err = parse_stage(&stage.replace("harmonic\"", "laplace\""), "s.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("laplace"), "{err}");
    }

    #[test]
    fn natnet_inputs_are_typed_as_the_docs_spell_them() {
        for spelling in ["natnet", "nat_net"] {
            let text = format!("[character]\nprocedural = \"hand\"\n[[inputs]]\ntype = \"{spelling}\"\nurl = \"natnet://127.0.0.1:1511\"\n");
            let c = parse_stage(&text, "s.toml").unwrap_or_else(|e| panic!("{spelling}: {e}"));
            assert!(matches!(c.inputs[0], InputConfig::NatNet(_)), "{spelling}");
        }
    }

    #[test]
    fn syntax_errors_name_their_line() {
        let err = parse_stage("[solver]\nrate_hz = = 3\n", "s.toml").unwrap_err();
        assert!(err.to_string().contains("line 2"), "{err}");
    }

    #[test]
    fn character_must_be_one_of_procedural_or_path() {
        let err = parse_stage("[[inputs]]\ntype = \"synthetic\"\n", "s.toml").unwrap_err();
        let s = err.to_string();
        assert!(s.contains("character: missing"), "{s}");
        assert!(s.contains("needs a procedural character"), "{s}");
    }

    /// Every problem of the section at once, each at its line, with the rule across
    /// sections (writing needs a character file).
    #[test]
    fn bad_calibration_keys_are_reported_together() {
        let text = r#"
[character]
procedural = "body"

[[inputs]]
type = "replay"
session = "body_rom"

[calibration]
first_secs = -2
frames = 0
marker_set = "vicon-blue"
write = true
"#;
        let err = parse_stage(text, "s.toml").unwrap_err().to_string();
        for want in [
            "line 10: calibration.first_secs: must be more than 0",
            "line 11: calibration.frames: must be 1 to 1000",
            "line 12: calibration.marker_set: no such table \"vicon-blue\"",
            "line 13: calibration.write: writing the layout needs a character file",
        ] {
            assert!(err.contains(want), "{want:?} not in:\n{err}");
        }
        let ok = text
            .replace("first_secs = -2", "first_secs = 5")
            .replace("frames = 0", "frames = 12")
            .replace("\"vicon-blue\"", "\"plug-in-gait\"")
            .replace("write = true", "always = true");
        let c = parse_stage(&ok, "s.toml").unwrap();
        assert_eq!(c.calibration.first_secs, Some(5.0));
        assert!(c.calibration.always);
    }
}
