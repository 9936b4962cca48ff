//! `rigless calibrate CHARACTER TAKE`: places a take's markers on a character (which bone
//! carries each label, its offset there, the actor's scale), prints the table, and with
//! `--write` stores the layout in the character file.

use anyhow::{bail, Context, Result};
use glam::DVec3;
use rigless::calibrate::labels::MapEntry;
use rigless::calibrate::layout::write_into;
use rigless::calibrate::marker_sets::{by_name, MARKER_SETS};
use rigless::calibrate::{calibrate, Calibration, CalibrationOptions, DEFAULT_FRAMES};
use rigless::character::demo::{demo_body, demo_hand};
use rigless::character::file::load_character;
use rigless::character::roles::{recognise, Role};
use rigless::character::skeleton::Joint;
use rigless::character::Character;
use rigless::replay::bvh::parse_bvh;
use rigless::replay::recording::{Recording, DEFAULT_BVH_METRES_PER_UNIT};
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// The character: `hand`, `body` (the procedural ones) or a character file (TOML).
    character: String,
    /// The take: C3D, Qualisys TSV, BVH or session file. A BVH's joints are taken as
    /// points at the character's joints of the same roles (from their names), not as
    /// markers on the skin.
    take: PathBuf,
    /// How many frames to fit, chosen over the take to cover its range of motion (and
    /// the one where the actor stands most like the character's rest pose).
    #[arg(long, default_value_t = DEFAULT_FRAMES)]
    frames: usize,
    /// Only frames in this span of the take, seconds: `START..END`.
    #[arg(long, value_name = "START..END")]
    span: Option<String>,
    /// The marker-set table: `auto` (the one that knows most labels) or a name
    /// (plug-in-gait, cmu-41, isb, davis, motive-baseline, dfki-hand, rigless-body,
    /// rigless-hand).
    #[arg(long, default_value = "auto")]
    marker_set: String,
    /// Write the layout (`[[markers]]`, replacing the file's) and the scale
    /// (`[calibration] marker_scale`) into the character file, keeping the old file as
    /// FILE.bak.
    #[arg(long)]
    write: bool,
    /// Metres per BVH unit.
    #[arg(long, default_value_t = DEFAULT_BVH_METRES_PER_UNIT)]
    bvh_scale: f64,
    /// Print the result as one JSON object.
    #[arg(long)]
    json: bool,
}

/// What a calibration needs of a character.
struct Target {
    character: Character,
    roles: Vec<Option<Role>>,
    map: Vec<MapEntry>,
    /// Its file (none for a procedural one).
    file: Option<PathBuf>,
}

/// The character named on the command line.
fn load(spec: &str) -> Result<Target> {
    if spec == "hand" || spec == "body" {
        let character = if spec == "hand" {
            demo_hand()
        } else {
            demo_body()
        };
        let roles = recognise(&character.skeleton.joints, &[]);
        return Ok(Target {
            character,
            roles,
            map: Vec::new(),
            file: None,
        });
    }
    let path = PathBuf::from(spec);
    let loaded = load_character(&path)?;
    let map = loaded
        .calibration_map
        .iter()
        .map(|(glob, target)| MapEntry {
            glob: glob.clone(),
            target: target.clone(),
        })
        .collect();
    Ok(Target {
        character: loaded.character,
        roles: loaded.joint_roles,
        map,
        file: Some(path),
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

/// `START..END` in seconds.
fn parse_span(s: &str) -> Result<(f64, f64)> {
    let (a, b) = s
        .split_once("..")
        .with_context(|| format!("--span {s:?}: expected START..END in seconds"))?;
    let (a, b): (f64, f64) = (
        a.trim()
            .parse()
            .with_context(|| format!("--span start {a:?}"))?,
        b.trim()
            .parse()
            .with_context(|| format!("--span end {b:?}"))?,
    );
    if !(a.is_finite() && b.is_finite() && 0.0 <= a && a < b) {
        bail!("--span {s:?}: the start must be zero or more and before the end");
    }
    Ok((a, b))
}

pub fn run(a: CalibrateArgs) -> Result<()> {
    if !(1..=1000).contains(&a.frames) {
        bail!("--frames must be 1 to 1000, got {}", a.frames);
    }
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
    let span_s = a.span.as_deref().map(parse_span).transpose()?;
    let Target {
        character: ch,
        roles,
        map,
        file,
    } = load(&a.character)?;
    if a.write && file.is_none() {
        bail!(
            "--write needs a character file; the procedural {} has none (the layout is printed instead)",
            a.character
        );
    }
    let rec = Recording::load_with(&a.take, a.bvh_scale)?;
    let is_bvh = a
        .take
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("bvh"));
    let mut map = map;
    if is_bvh {
        map.extend(bvh_roles(&a.take, a.bvh_scale)?);
    }
    let opts = CalibrationOptions {
        frames: a.frames,
        span_s,
        marker_set,
        map,
        markers_on_skin: !is_bvh,
        ..CalibrationOptions::default()
    };
    if !a.json {
        eprintln!(
            "calibrating {} ({} labels, {} frames at {} Hz) onto {} ...",
            a.take.display(),
            rec.labels.len(),
            rec.frames.len(),
            rec.rate_hz,
            ch.name
        );
    }
    let t0 = std::time::Instant::now();
    let cal = calibrate(&ch, &roles, rec.as_take(), &opts)?;
    let seconds = t0.elapsed().as_secs_f64();
    if a.json {
        println!("{}", serde_json::to_string(&json(&cal, &rec, seconds))?);
    } else {
        print_table(&cal, &rec, seconds);
    }
    if let (true, Some(path)) = (a.write, &file) {
        write(path, &cal)?;
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

/// `FILE.bak` beside `path`.
fn backup_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".bak");
    path.with_file_name(name)
}

/// Writes the calibration into the character file, the old one kept as `FILE.bak`.
fn write(path: &Path, cal: &Calibration) -> Result<()> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let new = write_into(&text, &path.display().to_string(), cal)?;
    let backup = backup_path(path);
    std::fs::write(&backup, &text).with_context(|| format!("writing {}", backup.display()))?;
    std::fs::write(path, new).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// The calibration as one JSON object.
fn json(cal: &Calibration, rec: &Recording, seconds: f64) -> serde_json::Value {
    serde_json::json!({
        "take": rec.name,
        "marker_set": cal.marker_set.map(|(s, n)| serde_json::json!({"name": s, "labels_known": n})),
        "scale": cal.scale,
        "frames": cal.frames,
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
            "residual_mm_max": p.residual_mm_max,
            "frames": p.frames,
            "flag": p.flag.as_ref().map(ToString::to_string),
        })).collect::<Vec<_>>(),
        "left_out": cal.left_out.iter().map(|(l, why)| serde_json::json!({"label": l, "why": why.to_string()})).collect::<Vec<_>>(),
    })
}

/// The calibration as a table.
fn print_table(cal: &Calibration, rec: &Recording, seconds: f64) {
    match cal.marker_set {
        Some((name, n)) => println!(
            "marker set   {name} (knows {n} of the take's {} labels)",
            rec.labels.len()
        ),
        None => println!("marker set   none knows these labels"),
    }
    let span = |f: &usize| *f as f64 / rec.rate_hz;
    println!(
        "frames       {} used, from {:.2} s to {:.2} s",
        cal.frames.len(),
        cal.frames.first().map_or(0.0, span),
        cal.frames.last().map_or(0.0, span)
    );
    println!(
        "scale        the actor is {:.3} times the character (marker_scale {:.5})",
        1.0 / cal.scale,
        cal.scale
    );
    println!(
        "fit          residual RMS {:.2} mm, max {:.2} mm; {} iterations, {:.2} s",
        cal.residual_mm_rms, cal.residual_mm_max, cal.report.iterations, seconds
    );
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
    for (label, why) in &cal.left_out {
        println!("{label:<12} left out: {why}");
    }
}
