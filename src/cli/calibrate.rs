//! `rigless calibrate CHARACTER TAKE`: places a take's markers on a character (which bone
//! carries each label, its offset there, the actor's scale), prints the table, and with
//! `--write` stores the layout in the character file.

use anyhow::{bail, Context, Result};
use glam::DVec3;
use rigless::calibrate::labels::{map_entries, MapEntry};
use rigless::calibrate::marker_sets::{by_name, MARKER_SETS};
use rigless::calibrate::points::PointFilter;
use rigless::calibrate::scale::ScaleStart;
use rigless::calibrate::{calibrate, Calibration, CalibrationOptions, Verdict, DEFAULT_FRAMES};
use rigless::character::bind_params::BindParams;
use rigless::character::demo::{body_bind_params, demo_body, demo_hand, hand_bind_params};
use rigless::character::file::{load_character, LoadedCharacter};
use rigless::character::roles::{recognise, Role};
use rigless::character::skeleton::Joint;
use rigless::character::Character;
use rigless::daemon::capture::capture;
use rigless::daemon::live_calibration::write_layout;
use rigless::daemon::offline::{replay_offline, OfflineOptions, OfflineReport};
use rigless::input::config::InputConfig;
use rigless::replay::bvh::parse_bvh;
use rigless::replay::recording::{Recording, DEFAULT_BVH_METRES_PER_UNIT};
use rigless::runtime::clock::{Clock, SystemClock};
use rigless::solve::frame::SolverParams;
use std::path::{Path, PathBuf};
use std::sync::Arc;

#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// The character: `hand`, `body` (the procedural ones) or a character file (TOML).
    character: String,
    /// The take: C3D, Qualisys TSV, BVH or session file, or a live input URL
    /// (osc://, vmc://, natnet://, vrpn://) captured for `--seconds`. A BVH's joints are
    /// taken as points at the character's joints of the same roles (from their names),
    /// not as markers on the skin.
    take: String,
    /// With a live input URL: seconds to capture (the actor stands in the character's
    /// rest pose, then moves every joint).
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Metres per sender unit of a live input (0.001 for a millimetre sender; osc://
    /// only).
    #[arg(long, default_value_t = 1.0)]
    scale: f64,
    /// The live sender's up axis is Z (osc:// only).
    #[arg(long)]
    z_up: bool,
    /// Which frames to fit: `auto` (20, chosen over the take to cover its range of
    /// motion, with the one where the actor stands most like the character's rest
    /// pose), a count (`30`), or a span of the take in seconds to choose them from
    /// (`0..8`).
    #[arg(long, default_value = "auto", value_name = "auto|N|START..END")]
    frames: String,
    /// How many frames to fit (with `--frames START..END`, or instead of a count there).
    #[arg(long, value_name = "N")]
    count: Option<usize>,
    /// The marker-set table: `auto` (the one that knows most labels) or a name
    /// (plug-in-gait, cmu-41, isb, davis, motive-baseline, motive-conventional,
    /// dfki-hand, rigless-body, rigless-hand).
    #[arg(long, default_value = "auto")]
    marker_set: String,
    /// Labels that are no markers on the actor, as globs (`*` any run, `?` one
    /// character, any case; comma-separated or the option repeated): a prop, another
    /// actor, a reference marker. Model outputs, unlabelled points, segment axes, other
    /// subjects, fixed points and props are left out without it, each with its reason.
    #[arg(long, value_name = "GLOBS", value_delimiter = ',')]
    exclude: Vec<String>,
    /// Labels to take whatever the rules and --exclude say (globs as for --exclude);
    /// with `--exclude '*'`, the only ones taken.
    #[arg(long, value_name = "GLOBS", value_delimiter = ',')]
    include: Vec<String>,
    /// Write the layout (`[[markers]]`, replacing the file's) and the scale
    /// (`[calibration] marker_scale`) into the character file, keeping the old file as
    /// FILE.bak.
    #[arg(long)]
    write: bool,
    /// Metres per BVH unit.
    #[arg(long, default_value_t = DEFAULT_BVH_METRES_PER_UNIT)]
    bvh_scale: f64,
    /// Then replay the take through the live pipeline at 120 Hz with the layout and
    /// scale found, and report what a stage would see: labels fed, samples held,
    /// misfit, bone lengths, limits, inverted tets and frame times.
    #[arg(long)]
    check: bool,
    /// Print the result as one JSON object.
    #[arg(long)]
    json: bool,
    /// A take of several performers: calibrate this one's labels (`Ann` for `Ann:LFHD`,
    /// the subject an `[[actors]]` entry claims; "" for labels without a prefix). Without
    /// it the subject with most labels is taken and the others are left out, named.
    #[arg(long, value_name = "NAME")]
    actor: Option<String>,
    /// A take of several performers: calibrate each (every subject with at least 3
    /// labels), a table and a verdict each. With --write, each performer's layout goes
    /// into a copy of the character file named after it beside it (`body-Ann.toml`), one
    /// for each `[[actors]]` entry of a stage.
    #[arg(long, conflicts_with = "actor")]
    actors: bool,
}

/// Labels a subject needs to be calibrated as a performer by `--actors` (a prop's one
/// or two markers are not one).
const PERFORMER_LABELS: usize = 3;

/// The options every calibration of a run shares, read from the arguments.
#[derive(Clone, Copy)]
struct Settings {
    frames: usize,
    span_s: Option<(f64, f64)>,
    marker_set: Option<&'static rigless::calibrate::marker_sets::MarkerSet>,
}

/// What a calibration needs of a character.
struct Target {
    character: Character,
    bind: BindParams,
    roles: Vec<Option<Role>>,
    map: Vec<MapEntry>,
    /// Its file (none for a procedural one).
    file: Option<PathBuf>,
    /// The file as loaded (for the bind settings of a new layout).
    loaded: Option<LoadedCharacter>,
}

/// The character named on the command line.
fn load(spec: &str) -> Result<Target> {
    if spec == "hand" || spec == "body" {
        let (character, bind) = if spec == "hand" {
            (demo_hand(), hand_bind_params())
        } else {
            (demo_body(), body_bind_params())
        };
        let roles = recognise(&character.skeleton.joints, &[]);
        return Ok(Target {
            loaded: None,
            character,
            bind,
            roles,
            map: Vec::new(),
            file: None,
        });
    }
    let path = PathBuf::from(spec);
    let loaded = load_character(&path)?;
    Ok(Target {
        character: loaded.character.clone(),
        bind: loaded.bind.clone(),
        roles: loaded.joint_roles.clone(),
        map: map_entries(&loaded.calibration_map),
        file: Some(path),
        loaded: Some(loaded),
    })
}

/// A BVH take's joints (its labels) with their humanoid roles, recognised from their
/// names and hierarchy as a character's are, as map entries (label to role).
fn bvh_roles(path: &Path, metres_per_unit: f64) -> Result<Vec<MapEntry>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    let bvh = parse_bvh(&text, metres_per_unit).with_context(|| format!("{}", path.display()))?;
    let rest = |j: usize| bvh.positions.first().map_or(DVec3::ZERO, |f| f[j]);
    let joints: Vec<Joint> = (0..bvh.joint_names.len())
        .map(|j| Joint {
            name: bvh.joint_names[j].clone(),
            parent: bvh.parents[j],
            rest: rest(j),
            limits: None,
            bend_axis: DVec3::X,
        })
        .collect();
    Ok(recognise(&joints, &[])
        .into_iter()
        .zip(&bvh.joint_names)
        .filter_map(|(role, name)| {
            role.map(|r| MapEntry {
                glob: name.clone(),
                target: r.to_string(),
            })
        })
        .collect())
}

/// `--frames` (and `--count`): how many frames, and the span to choose them from.
fn parse_frames(spec: &str, count: Option<usize>) -> Result<(usize, Option<(f64, f64)>)> {
    let (n, span) = match spec.trim() {
        "auto" => (count.unwrap_or(DEFAULT_FRAMES), None),
        s if s.contains("..") => (count.unwrap_or(DEFAULT_FRAMES), Some(parse_span(s)?)),
        s => {
            let n: usize = s.parse().with_context(|| {
                format!("--frames {s:?}: expected auto, a count or START..END in seconds")
            })?;
            if count.is_some_and(|c| c != n) {
                bail!("--frames {n} and --count {count:?} disagree");
            }
            (n, None)
        }
    };
    if !(1..=1000).contains(&n) {
        bail!("the frames to fit must be 1 to 1000, got {n}");
    }
    Ok((n, span))
}

/// `START..END` in seconds.
fn parse_span(s: &str) -> Result<(f64, f64)> {
    let (a, b) = s
        .split_once("..")
        .with_context(|| format!("--frames {s:?}: expected START..END in seconds"))?;
    let (a, b): (f64, f64) = (
        a.trim()
            .parse()
            .with_context(|| format!("--frames: the start {a:?} is not a number"))?,
        b.trim()
            .parse()
            .with_context(|| format!("--frames: the end {b:?} is not a number"))?,
    );
    if !(a.is_finite() && b.is_finite() && 0.0 <= a && a < b) {
        bail!("--frames {s:?}: the start must be zero or more and before the end");
    }
    Ok((a, b))
}

pub fn run(a: CalibrateArgs) -> Result<()> {
    let (frames, span_s) = parse_frames(&a.frames, a.count)?;
    if !(a.bvh_scale.is_finite() && a.bvh_scale > 0.0) {
        bail!("--bvh-scale must be positive, got {}", a.bvh_scale);
    }
    let marker_set = match a.marker_set.as_str() {
        "auto" => None,
        name => Some(by_name(name).with_context(|| {
            let names: Vec<&str> = MARKER_SETS.iter().map(|s| s.name).collect();
            format!(
                "--marker-set {name:?}: no such table (auto, {})",
                names.join(", ")
            )
        })?),
    };
    let settings = Settings {
        frames,
        span_s,
        marker_set,
    };
    let target = load(&a.character)?;
    if a.write && target.file.is_none() {
        bail!(
            "--write needs a character file; the procedural {0} has none (write one with `rigless export-character {0} DIR`, then calibrate DIR/{0}.toml)",
            a.character
        );
    }
    let (mut rec, is_bvh) = take(&a)?;
    let subjects = rec.subjects();
    let named = |subjects: &[String]| {
        subjects
            .iter()
            .map(|s| format!("{s:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if a.actors {
        return calibrate_actors(&a, &settings, target, &rec, is_bvh);
    }
    if let Some(actor) = &a.actor {
        rec.keep_subject(actor);
        if rec.labels.is_empty() {
            bail!(
                "--actor {actor:?}: {} has no label of that subject (its subjects: {})",
                a.take,
                named(&subjects)
            );
        }
    }
    let write_to = target.file.clone().filter(|_| a.write);
    calibrate_take(&a, &settings, target, &rec, is_bvh, write_to.as_deref())
}

/// `--actors`: each performer of the take calibrated on its own labels, its layout
/// written (with `--write`) into a copy of the character file named after it.
fn calibrate_actors(
    a: &CalibrateArgs,
    settings: &Settings,
    target: Target,
    rec: &Recording,
    is_bvh: bool,
) -> Result<()> {
    use rigless::markers::index::subject_of;
    let count = |s: &str| {
        rec.labels
            .iter()
            .filter(|l| subject_of(l).eq_ignore_ascii_case(s))
            .count()
    };
    let performers: Vec<String> = rec
        .subjects()
        .into_iter()
        .filter(|s| count(s) >= PERFORMER_LABELS)
        .collect();
    if performers.len() < 2 {
        let whose: Vec<String> = rec
            .subjects()
            .iter()
            .map(|s| format!("{s:?} ({} labels)", count(s)))
            .collect();
        bail!(
            "--actors: {} has {} performer{} with at least {PERFORMER_LABELS} labels (subjects: {}); --actors needs two or more (without it one is calibrated)",
            a.take,
            performers.len(),
            if performers.len() == 1 { "" } else { "s" },
            whose.join(", ")
        );
    }
    let mut failed = Vec::new();
    for (i, subject) in performers.iter().enumerate() {
        let mut mine = rec.clone();
        mine.keep_subject(subject);
        let name = if subject.is_empty() {
            "unprefixed"
        } else {
            subject.as_str()
        };
        let copy = match (&target.file, a.write) {
            (Some(path), true) => Some(actor_copy(path, name)?),
            _ => None,
        };
        if !a.json {
            println!(
                "{}actor {name} ({} labels)",
                if i > 0 { "\n" } else { "" },
                mine.labels.len()
            );
        }
        let target = load(&a.character)?;
        if let Err(e) = calibrate_take(a, settings, target, &mine, is_bvh, copy.as_deref()) {
            eprintln!("actor {name}: {e:#}");
            failed.push(name.to_owned());
        }
    }
    match failed.is_empty() {
        true => Ok(()),
        false => bail!(
            "{}: the calibration of {} failed (said above)",
            a.take,
            failed.join(", ")
        ),
    }
}

/// A copy of the character file at `path` for actor `name`, beside it
/// (`body.toml` → `body-Ann.toml`), for its layout to be written into.
fn actor_copy(path: &Path, name: &str) -> Result<PathBuf> {
    let stem = path.file_stem().unwrap_or_default().to_string_lossy();
    let safe: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    let copy = path.with_file_name(format!("{stem}-{safe}.toml"));
    std::fs::copy(path, &copy)
        .with_context(|| format!("copying {} to {}", path.display(), copy.display()))?;
    Ok(copy)
}

/// Calibrates `rec` onto `target` as the arguments say: the table (or JSON), the check
/// when asked, the verdict, and the layout written into `write_to` when given.
fn calibrate_take(
    a: &CalibrateArgs,
    settings: &Settings,
    target: Target,
    rec: &Recording,
    is_bvh: bool,
    write_to: Option<&Path>,
) -> Result<()> {
    let Target {
        character: ch,
        bind,
        loaded,
        roles,
        map,
        ..
    } = target;
    let Settings {
        frames,
        span_s,
        marker_set,
    } = *settings;
    let mut map = map;
    if is_bvh {
        map.extend(bvh_roles(Path::new(&a.take), a.bvh_scale)?);
    }
    let opts = CalibrationOptions {
        frames,
        span_s,
        marker_set,
        map,
        points: PointFilter {
            exclude: a.exclude.clone(),
            include: a.include.clone(),
        },
        markers_on_skin: !is_bvh,
        max_marker_distance_m: bind.max_marker_distance_m,
        ..CalibrationOptions::default()
    };
    if !a.json {
        eprintln!(
            "calibrating {} ({} labels, {} frames at {:.1} Hz) onto {} ...",
            a.take,
            rec.labels.len(),
            rec.frames.len(),
            rec.rate_hz,
            ch.name
        );
    }
    let t0 = std::time::Instant::now();
    let mut cal = calibrate(&ch, &roles, rec.as_take(), &opts)?;
    let seconds = t0.elapsed().as_secs_f64();
    let verdict = cal.verdict();
    // What is written or checked binds: labels the bind refuses are left out first.
    let bind = loaded.map_or(bind, |l| l.bind_for(&cal.layout(&ch)));
    let binds = (a.check || a.write) && verdict != Verdict::Failed;
    let rig = if binds {
        Some(Arc::new(
            cal.bind(&ch, &bind, &mut |_, _| {})
                .context("binding the calibrated layout")?,
        ))
    } else {
        None
    };
    // Labels the bind refused may change the verdict.
    let verdict = cal.verdict();
    if !a.json {
        print_table(&cal, rec, seconds);
    }
    let checked = match rig.filter(|_| a.check && verdict != Verdict::Failed) {
        Some(rig) => {
            if !a.json {
                eprintln!("replaying the take with this layout at 120 Hz ...");
            }
            Some(check(rig, rec, &cal)?)
        }
        None => None,
    };
    if a.json {
        let mut v = json(&cal, rec, seconds);
        v["check"] = serde_json::to_value(&checked)?;
        println!("{}", serde_json::to_string(&v)?);
    } else {
        if let Some(r) = &checked {
            print_check(r);
        }
        print_verdict(&cal, write_to.is_some());
    }
    if verdict == Verdict::Failed {
        bail!(
            "{}: the calibration failed ({}); nothing was written",
            a.take,
            cal.concerns()
                .iter()
                .filter(|c| c.verdict() == Verdict::Failed)
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
    if let Some(path) = write_to {
        write_layout(path, &cal)?;
        if !a.json {
            println!(
                "wrote {} markers and marker_scale {:.5} into {} (the old file is {})",
                cal.placed.len(),
                cal.scale,
                path.display(),
                backup_path(path).display()
            );
        }
    }
    Ok(())
}

/// The verdict and its reasons, last, where a reader looks.
fn print_verdict(cal: &Calibration, write: bool) {
    let concerns = cal.concerns();
    println!();
    println!("verdict      {}", cal.verdict());
    for c in &concerns {
        println!("  {}: {c}", c.verdict());
    }
    if cal.verdict() == Verdict::Doubtful && write {
        println!("  written all the same: look at the labels named above before a session");
    }
}

/// The take: a file, or what a live input URL sent in `--seconds`; and whether it is a
/// BVH (joint centres, not markers).
fn take(a: &CalibrateArgs) -> Result<(Recording, bool)> {
    if !a.take.contains("://") {
        let path = Path::new(&a.take);
        let is_bvh = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("bvh"));
        return Ok((Recording::load_with(path, a.bvh_scale)?, is_bvh));
    }
    if !(a.scale.is_finite() && a.scale > 0.0) {
        bail!(
            "--scale must be a positive number of metres per unit, got {:?}",
            a.scale
        );
    }
    let cfg = InputConfig::from_url(&a.take)?.with_sender_units(a.scale, a.z_up);
    if !a.json {
        eprintln!(
            "capturing {} s from {}: stand in the character's rest pose, then move every joint ...",
            a.seconds, a.take
        );
    }
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::new());
    let (rec, lines) = capture(
        &[cfg],
        Path::new("."),
        &clock,
        a.seconds,
        &a.take,
        &rigless::markers::index::SubjectFilter::One,
    )?;
    if !a.json {
        for l in lines.iter().chain(&rec.warnings) {
            eprintln!("  {l}");
        }
    }
    Ok((rec, false))
}

/// `rec` replayed through the live pipeline onto `rig` (bound with the layout of `cal`)
/// with the scale of `cal`.
fn check(
    rig: Arc<rigless::rig::bind::Rig>,
    rec: &Recording,
    cal: &Calibration,
) -> Result<OfflineReport> {
    let opts = OfflineOptions {
        marker_scale: cal.scale,
        ..OfflineOptions::default()
    };
    replay_offline(rig, SolverParams::default(), rec, opts)?
        .context("no label of the take feeds a placed marker")
}

/// Where the scale's fit started, in words.
fn scale_start(start: &ScaleStart) -> String {
    let frame = format!("the rest-like frame alone gave {:.4}", start.rest_frame);
    match start.segments {
        None => format!("fitted from {frame} (too few labels share a bone for segment lengths)"),
        Some(s) => format!(
            "fitted from {}: {} segment lengths over {} frames gave {:.4}, {frame}",
            if start.from_segments {
                "the segment lengths"
            } else {
                "the rest-like frame"
            },
            s.pairs,
            s.frames,
            s.scale
        ),
    }
}

/// `FILE.bak` beside `path`.
fn backup_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".bak");
    path.with_file_name(name)
}

/// The calibration as one JSON object.
fn json(cal: &Calibration, rec: &Recording, seconds: f64) -> serde_json::Value {
    serde_json::json!({
        "take": rec.name,
        "verdict": cal.verdict(),
        "concerns": cal.concerns().iter().map(|c| serde_json::json!({"verdict": c.verdict(), "why": c.to_string()})).collect::<Vec<_>>(),
        "markers": cal.markers,
        "marker_set": cal.marker_set.map(|(s, n)| serde_json::json!({"name": s, "labels_known": n})),
        "marker_set_declined": cal.declined_set.map(|(s, n)| serde_json::json!({"name": s, "labels_known": n})),
        "scale": cal.scale,
        "scale_start": {
            "rest_frame": cal.scale_start.rest_frame,
            "segments": cal.scale_start.segments,
            "from_segments": cal.scale_start.from_segments,
        },
        "frames": cal.frames,
        "rest_frame": cal.rest_frame,
        "whole_span_mm_rms": cal.whole_span_mm,
        "rest_turns_deg": cal.rest_turns.iter().map(|(j, deg)| serde_json::json!({"joint": j, "deg": deg})).collect::<Vec<_>>(),
        "bent_knees_deg": cal.bent_knees.iter().map(|(j, deg)| serde_json::json!({"joint": j, "least_deg": deg})).collect::<Vec<_>>(),
        "floor": cal.floor.map(|f| serde_json::json!({
            "lowest_skin_m": f.lowest_skin_m,
            "lowest_marker_m": f.lowest_marker_m,
            "floor_shown": f.floor_shown(),
            "foot_marker_above_skin_m": f.foot_marker_above_skin_m,
            "soles_off_m": f.soles_off_m(),
        })),
        "residual_mm_rms": cal.residual_mm_rms,
        "residual_mm_max": cal.residual_mm_max,
        "iterations": cal.report.iterations,
        "seconds": seconds,
        "placed": cal.placed.iter().map(|p| serde_json::json!({
            "label": p.label,
            "bone": p.joint_name,
            "offset_m": p.offset_m.to_array(),
            "skin_mm": p.skin_m * 1e3,
            "from": p.source.to_string(),
            "residual_mm_rms": p.residual_mm_rms,
            "from_template_mm": p.from_template_m.map(|d| d * 1e3),
            "residual_mm_max": p.residual_mm_max,
            "frames": p.frames,
            "flag": p.flag.as_ref().map(ToString::to_string),
        })).collect::<Vec<_>>(),
        "left_out": cal.left_out.iter().map(|(l, why)| serde_json::json!({"label": l, "why": why.to_string()})).collect::<Vec<_>>(),
    })
}

/// What the replay with the calibrated layout did.
fn print_check(r: &OfflineReport) {
    println!();
    println!(
        "replayed     {} frames at 120 Hz: {} labels fed, {:.1} % of their samples held",
        r.frames,
        r.labels_fed,
        100.0 * r.held_share
    );
    println!(
        "misfit       {:.1} mm RMS, {:.1} mm max (character millimetres)",
        r.residual_mm_rms, r.residual_mm_max
    );
    println!(
        "character    bone length error {:.2} % at worst, joint limits exceeded by {:.2}° at worst, {} inverted tets at worst",
        100.0 * r.bone_length_error_max,
        r.joint_limit_violation_deg_max,
        r.inverted_tets_max
    );
    println!(
        "frame time   p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms; {} frames stopped by their deadline",
        r.frame_ms_p50, r.frame_ms_p99, r.frame_ms_max, r.deadline_stops
    );
}

/// The calibration as a table.
fn print_table(cal: &Calibration, rec: &Recording, seconds: f64) {
    let share = |n: usize| 100.0 * n as f64 / cal.markers.max(1) as f64;
    match (cal.marker_set, cal.declined_set) {
        (Some((name, n)), _) => println!(
            "marker set   {name} (knows {n} of the take's {} marker labels, {:.0} %)",
            cal.markers,
            share(n)
        ),
        (None, Some((name, n))) => println!(
            "marker set   none: the nearest, {name}, knows {n} of {} marker labels ({:.0} %), \
             too few to trust (--marker-set {name} takes it)",
            cal.markers,
            share(n)
        ),
        (None, None) => println!("marker set   none knows these labels"),
    }
    println!(
        "labels       {} in the take: {} may be markers, {} placed",
        rec.labels.len(),
        cal.markers,
        cal.placed.len()
    );
    let span = |f: &usize| *f as f64 / rec.rate_hz;
    println!(
        "frames       {} used, from {:.2} s to {:.2} s; the actor stands most like the character's rest pose at {:.2} s{}",
        cal.frames.len(),
        cal.frames.first().map_or(0.0, span),
        cal.frames.last().map_or(0.0, span),
        span(&cal.rest_frame),
        match cal.whole_span_mm {
            Some(mm) => format!(
                " (fitted near it: the whole take fits at {mm:.1} mm RMS)"
            ),
            None => String::new(),
        }
    );
    println!(
        "scale        the actor is {:.3} times the character (marker_scale {:.5}); {}",
        1.0 / cal.scale,
        cal.scale,
        scale_start(&cal.scale_start)
    );
    println!(
        "fit          residual RMS {:.2} mm, max {:.2} mm; {} iterations, {:.2} s",
        cal.residual_mm_rms, cal.residual_mm_max, cal.report.iterations, seconds
    );
    if let Some(f) = cal.floor {
        println!(
            "floor        the character's lowest point {:+.1} cm from y = 0 in the median frame used; the lowest marker {:+.1} cm{}",
            100.0 * f.lowest_skin_m,
            100.0 * f.lowest_marker_m,
            if f.floor_shown() {
                ""
            } else {
                " (too far for a foot's: the take does not show its floor)"
            }
        );
        if let Some(above) = f.foot_marker_above_skin_m {
            println!(
                "soles        the lowest marker, on a foot, {:+.1} cm above the character's lowest point in the median frame used",
                100.0 * above
            );
        }
    }
    println!();
    println!(
        "{:<12} {:<18} {:>27} {:>6} {:>6} {:>6} {:>7}  from",
        "label", "bone", "offset mm (x, y, z)", "skin", "rms", "max", "frames"
    );
    for p in &cal.placed {
        let o = p.offset_m * 1e3;
        println!(
            "{:<12} {:<18} {:>27} {:>6.1} {:>6.2} {:>6.2} {:>7}  {}{}",
            p.label,
            p.joint_name,
            format!("({:.1}, {:.1}, {:.1})", o.x, o.y, o.z),
            p.skin_m * 1e3,
            p.residual_mm_rms,
            p.residual_mm_max,
            p.frames,
            p.source,
            p.flag
                .as_ref()
                .map(|f| format!("  <- {f}"))
                .unwrap_or_default()
        );
    }
    // Labels left out for the same reason share a line.
    let mut reasons: Vec<(String, Vec<&str>)> = Vec::new();
    for (label, why) in &cal.left_out {
        let why = why.to_string();
        match reasons.iter_mut().find(|(w, _)| *w == why) {
            Some((_, labels)) => labels.push(label),
            None => reasons.push((why, vec![label])),
        }
    }
    for (why, labels) in &reasons {
        match labels.as_slice() {
            [one] => println!("{one:<12} left out: {why}"),
            many => println!(
                "{} labels left out: {why}:\n    {}",
                many.len(),
                many.join(" ")
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_auto_a_count_or_a_span() {
        assert_eq!(parse_frames("auto", None).unwrap(), (DEFAULT_FRAMES, None));
        assert_eq!(parse_frames("30", None).unwrap(), (30, None));
        assert_eq!(
            parse_frames("0..8.5", Some(12)).unwrap(),
            (12, Some((0.0, 8.5)))
        );
        for bad in ["8..2", "0", "1001", "many", "-1..3", "1..x"] {
            assert!(parse_frames(bad, None).is_err(), "{bad}");
        }
        assert!(parse_frames("30", Some(12)).is_err(), "a count twice");
    }
}
