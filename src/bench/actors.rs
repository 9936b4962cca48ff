//! The `actors` suite: stages of several performers. In real time on the system clock,
//! 1, 2, 4 and 8 procedural bodies (36 markers each) walking side by side at 120 Hz,
//! on every core and on one: each actor's frame time (p50, p99), missed ticks, deadline
//! stops. Then two real takes of the shared data folder put in one take behind two
//! subjects (every label fed to its own actor, each one's marker residual against the
//! same take solved alone), and a label swap injected between two bodies 0.3 m apart
//! (how far it pulls one actor's mesh towards the other, with the identity gate and
//! without).

use super::BenchError;
use crate::character::body::BodyMotion;
use crate::character::demo::{demo_body, Motion};
use crate::config::parse_stage;
use crate::daemon::stage::{Stage, StartOptions, Summary};
use crate::output::frame::DeformedFrame;
use crate::replay::bundled::{cast_take, CastMember};
use crate::replay::c3d::{write_c3d, Processor};
use crate::replay::recording::Recording;
use crate::runtime::clock::{Clock, ManualClock, SystemClock};
use glam::DVec3;
use std::path::Path;
use std::sync::Arc;

/// Subjects of the walkers, in order.
const SUBJECTS: [&str; 8] = ["A1", "A2", "A3", "A4", "A5", "A6", "A7", "A8"];

/// Metres between two walkers' lanes (along X).
const LANE_M: f64 = 1.0;

/// `n` bodies walking along +Z side by side, [`LANE_M`] apart, each its own take.
pub fn walkers(n: usize) -> Vec<CastMember> {
    SUBJECTS[..n.min(SUBJECTS.len())]
        .iter()
        .enumerate()
        .map(|(i, subject)| CastMember {
            subject,
            yaw_deg: 0.0,
            offset_m: [LANE_M * i as f64, 0.0, 0.0],
            enters_s: 0.0,
        })
        .collect()
}

/// A stage of `n` procedural bodies, each claiming its walker's subject, replaying
/// `take` (relative to the stage's folder), on `threads` solver threads (`None`: the
/// cores); no stream.
pub fn walkers_stage(n: usize, take: &str, threads: Option<usize>) -> String {
    let mut text = String::new();
    for s in &SUBJECTS[..n] {
        text +=
            &format!("[[actors]]\nname = \"{s}\"\nprocedural = \"body\"\nsubject = \"{s}\"\n\n");
    }
    if let Some(t) = threads {
        text += &format!("[solver]\nthreads = {t}\n\n");
    }
    text += &format!(
        "[[inputs]]\ntype = \"replay\"\npath = {take:?}\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n"
    );
    text
}

/// Writes a take of `cast` walking for `seconds` to `path` (C3D).
fn write_take(path: &Path, cast: &[CastMember], seconds: f64) -> Result<(), BenchError> {
    let (labels, frames) = cast_take(
        Arc::new(demo_body()),
        Motion::Body(BodyMotion::Walk),
        seconds,
        cast,
    );
    let bytes = write_c3d(&labels, 120.0, &frames, Processor::Intel)
        .map_err(|e| BenchError::case("walkers take", e))?;
    std::fs::write(path, bytes)?;
    Ok(())
}

/// Runs a stage config's text from `dir` on `clock` until its inputs end or `secs`.
pub fn run_stage(
    text: &str,
    dir: &Path,
    clock: Arc<dyn Clock>,
    secs: Option<f64>,
) -> Result<Summary, BenchError> {
    let cfg = parse_stage(text, "actors benchmark").map_err(|e| BenchError::case("stage", e))?;
    let stage = Stage::start_with(
        &cfg,
        dir,
        clock,
        StartOptions {
            stop_after_secs: secs,
            ..StartOptions::default()
        },
    )
    .map_err(|e| BenchError::case("stage", e))?;
    stage.join().map_err(|e| BenchError::case("stage", e))
}

/// One timing case: `n` bodies in real time.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TimingRecord {
    pub suite: &'static str,
    pub case: &'static str,
    pub bodies: usize,
    pub threads: usize,
    pub rate_hz: f64,
    pub seconds: f64,
    /// Over the actors: the median of their frame-time medians, and the largest of
    /// their 99th percentiles, ms (a frame: buffer, solve, full mesh).
    pub frame_ms_p50: f64,
    pub frame_ms_p99_max: f64,
    /// Ticks skipped because a solver thread fell a period behind (the most of any
    /// thread), and frames stopped by their deadline (all actors).
    pub missed_ticks: u64,
    pub deadline_stops: u64,
    /// Marker residual RMS, mm, the largest of any actor's.
    pub residual_mm_rms_max: f64,
}

fn timing(
    dir: &Path,
    n: usize,
    threads: Option<usize>,
    seconds: f64,
) -> Result<TimingRecord, BenchError> {
    let take = format!("walkers-{n}.c3d");
    write_take(&dir.join(&take), &walkers(n), seconds + 2.0)?;
    let text = walkers_stage(n, &take, threads);
    let s = run_stage(&text, dir, Arc::new(SystemClock::new()), Some(seconds))?;
    let mut p50: Vec<f64> = s.actors.iter().map(|a| a.status.frame_ms_p50).collect();
    let med = crate::runtime::stats::percentile(&mut p50, 0.5);
    let fold = |f: fn(&crate::daemon::pipeline::LoopStatus) -> f64| {
        s.actors.iter().map(|a| f(&a.status)).fold(0.0, f64::max)
    };
    Ok(TimingRecord {
        suite: "actors",
        case: if threads == Some(1) {
            "one core"
        } else {
            "all cores"
        },
        bodies: n,
        threads: threads
            .unwrap_or_else(|| crate::solve::config::SolverConfig::default().threads_for(n)),
        rate_hz: 120.0,
        seconds,
        frame_ms_p50: med,
        frame_ms_p99_max: fold(|st| st.frame_ms_p99),
        missed_ticks: s
            .actors
            .iter()
            .map(|a| a.status.overruns)
            .max()
            .unwrap_or(0),
        deadline_stops: s.actors.iter().map(|a| a.status.deadline_stops).sum(),
        residual_mm_rms_max: fold(|st| st.marker_residual_mm_rms),
    })
}

/// What a label swap between two actors did to one of them.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SwapRecord {
    pub suite: &'static str,
    pub case: &'static str,
    pub identity_gate: bool,
    /// How far apart the two bodies walk, metres, and the markers whose labels were
    /// swapped between them for `swap_secs`.
    pub apart_m: f64,
    pub markers_swapped: usize,
    pub swap_secs: f64,
    pub frames: usize,
    /// Frames in which a vertex of the first actor's mesh moved more than 0.1 m towards
    /// the other (against the same take without the swap), and the most it moved, m.
    pub frames_pulled: usize,
    pub worst_pull_m: f64,
    /// Samples the identity gate dropped.
    pub identity_gated: u64,
}

/// Pull towards the other actor beyond which a frame counts as pulled, metres.
pub const PULL_LIMIT_M: f64 = 0.1;

/// Two bodies walk side by side `apart_m` apart (Bob at +X), as a two-actor stage on a
/// manual clock; for one second the labels of six of their left-side markers are
/// swapped between them (Ann's label on Bob's marker and Bob's on Ann's). Ann's every
/// frame is compared with the same stage's without the swap. `identity_gate` off sets
/// `[buffer] identity_gate_m = 0`.
pub fn label_swap(dir: &Path, apart_m: f64, identity_gate: bool) -> Result<SwapRecord, BenchError> {
    const SWAP_FROM_S: f64 = 1.5;
    const SWAP_SECS: f64 = 1.0;
    let ch = demo_body();
    let cast = [
        CastMember {
            subject: "Ann",
            yaw_deg: 0.0,
            offset_m: [0.0; 3],
            enters_s: 0.0,
        },
        CastMember {
            subject: "Bob",
            yaw_deg: 0.0,
            offset_m: [apart_m, 0.0, 0.0],
            enters_s: 0.0,
        },
    ];
    let (labels, frames) = cast_take(
        Arc::new(ch.clone()),
        Motion::Body(BodyMotion::Walk),
        4.0,
        &cast,
    );
    let n = ch.markers.len();
    let swapped: Vec<usize> = ch
        .markers
        .iter()
        .enumerate()
        .filter(|(_, m)| m.name.starts_with('L'))
        .map(|(k, _)| k)
        .take(6)
        .collect();
    let gate = if identity_gate {
        ""
    } else {
        "[buffer]\nidentity_gate_m = 0.0\n"
    };
    let stage = format!(
        "[[actors]]\nname = \"Ann\"\nprocedural = \"body\"\nsubject = \"Ann\"\n[[actors]]\nname = \"Bob\"\nprocedural = \"body\"\nsubject = \"Bob\"\n{gate}[[inputs]]\ntype = \"replay\"\npath = \"swap.c3d\"\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n"
    );
    let ann_frames = |swap: bool| -> Result<(Vec<Arc<DeformedFrame>>, Summary), BenchError> {
        let frames: Vec<Vec<DVec3>> = frames
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let t = i as f64 / 120.0;
                let on = swap && (SWAP_FROM_S..SWAP_FROM_S + SWAP_SECS).contains(&t);
                let mut f = f.clone();
                if on {
                    for &k in &swapped {
                        f.swap(k, n + k);
                    }
                }
                f
            })
            .collect();
        let bytes = write_c3d(&labels, 120.0, &frames, Processor::Intel)
            .map_err(|e| BenchError::case("label swap", e))?;
        std::fs::write(dir.join("swap.c3d"), bytes)?;
        let (tx, rx) = crossbeam_channel::bounded(frames.len() * 2);
        let cfg =
            parse_stage(&stage, "label swap").map_err(|e| BenchError::case("label swap", e))?;
        let run = Stage::start_with(
            &cfg,
            dir,
            Arc::new(ManualClock::new(0.0)),
            StartOptions {
                frame_logs: vec![tx],
                ..StartOptions::default()
            },
        )
        .map_err(|e| BenchError::case("label swap", e))?;
        let summary = run.join().map_err(|e| BenchError::case("label swap", e))?;
        Ok((rx.try_iter().collect(), summary))
    };
    let (clean, _) = ann_frames(false)?;
    let (swap, summary) = ann_frames(true)?;
    let pulls: Vec<f64> = clean
        .iter()
        .zip(&swap)
        .map(|(c, s)| {
            c.vertices_m
                .iter()
                .zip(&s.vertices_m)
                .map(|(c, s)| f64::from(s.x - c.x))
                .fold(0.0, f64::max)
        })
        .collect();
    Ok(SwapRecord {
        suite: "actors",
        case: "label swap",
        identity_gate,
        apart_m,
        markers_swapped: swapped.len(),
        swap_secs: SWAP_SECS,
        frames: pulls.len(),
        frames_pulled: pulls.iter().filter(|p| **p > PULL_LIMIT_M).count(),
        worst_pull_m: pulls.iter().copied().fold(0.0, f64::max),
        identity_gated: summary.actors[0].status.buffer.identity_gated,
    })
}

/// Two real takes in one: each behind its subject, the second 3 m to the side.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RealPairRecord {
    pub suite: &'static str,
    pub case: &'static str,
    pub takes: [String; 2],
    /// Per actor: samples fed in the pair and alone (equal: none crossed), and the
    /// marker residual RMS in the pair and alone, mm.
    pub samples_pair: [u64; 2],
    pub samples_alone: [u64; 2],
    pub residual_mm_pair: [f64; 2],
    pub residual_mm_alone: [f64; 2],
}

/// The shared data's Plug-in Gait trial and CMU take, as subjects `A` and `B`, on two
/// procedural bodies (uncalibrated: the residuals are large, and what counts is that
/// each is the same as when its take is solved alone).
fn real_pair(data: &Path, dir: &Path) -> Result<Option<RealPairRecord>, BenchError> {
    let takes = [
        "c3d/real/pycgm_pig_movement_trial.c3d",
        "c3d/real/cmu_85_02.c3d",
    ];
    let mut recs = Vec::new();
    for t in takes {
        let path = data.join(t);
        if !path.is_file() {
            return Ok(None);
        }
        recs.push(Recording::load(&path).map_err(|e| BenchError::case(t, e))?);
    }
    let bare = |l: &str| crate::markers::index::subject_of(l).len();
    let mut labels = Vec::new();
    for (rec, s) in recs.iter().zip(["A", "B"]) {
        labels.extend(rec.labels.iter().map(|l| {
            let cut = bare(l);
            let l = if cut > 0 { &l[cut + 1..] } else { l.as_str() };
            format!("{s}:{l}")
        }));
    }
    let frames_n = recs.iter().map(|r| r.frames.len()).max().unwrap_or(0);
    let mut frames = vec![Vec::new(); frames_n];
    for (k, rec) in recs.iter().enumerate() {
        let shift = DVec3::X * 3.0 * k as f64;
        for (i, f) in frames.iter_mut().enumerate() {
            match rec.frames.get(i) {
                Some(r) => f.extend(r.iter().map(|p| *p + shift)),
                None => f.extend(std::iter::repeat_n(DVec3::NAN, rec.labels.len())),
            }
        }
    }
    let bytes = write_c3d(&labels, recs[0].rate_hz, &frames, Processor::Intel)
        .map_err(|e| BenchError::case("real pair", e))?;
    std::fs::write(dir.join("pair.c3d"), bytes)?;
    let actor = |s: &str| {
        format!("[[actors]]\nname = \"{s}\"\nprocedural = \"body\"\nsubject = \"{s}\"\n\n")
    };
    let input = "[[inputs]]\ntype = \"replay\"\npath = \"pair.c3d\"\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n";
    let run = |text: String| run_stage(&text, dir, Arc::new(ManualClock::new(0.0)), None);
    let pair = run(format!("{}{}{input}", actor("A"), actor("B")))?;
    let alone = [
        run(format!("{}{input}", actor("A")))?,
        run(format!("{}{input}", actor("B")))?,
    ];
    let fed = |s: &Summary, i: usize| {
        let b = &s.actors[i].status.buffer;
        b.accepted + b.occluded
    };
    Ok(Some(RealPairRecord {
        suite: "actors",
        case: "two real takes in one",
        takes: takes.map(|t| t.rsplit('/').next().unwrap_or(t).to_owned()),
        samples_pair: [fed(&pair, 0), fed(&pair, 1)],
        samples_alone: [fed(&alone[0], 0), fed(&alone[1], 0)],
        residual_mm_pair: [0, 1].map(|i| pair.actors[i].status.marker_residual_mm_rms),
        residual_mm_alone: [0, 1].map(|i| alone[i].actors[0].status.marker_residual_mm_rms),
    }))
}

/// Runs the suite: timing cases of `seconds` each, the label swap, the real pair when
/// `data` has its takes.
pub fn suite(
    data: &Path,
    seconds: f64,
    json: bool,
    out: &mut dyn std::io::Write,
) -> Result<(), BenchError> {
    let dir = std::env::temp_dir().join(format!("rigless-bench-actors-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let result = (|| {
        if !json {
            writeln!(out, "case        bodies threads  frame ms p50  p99 (worst actor)  missed ticks  deadline stops  residual mm")?;
        }
        for threads in [None, Some(1)] {
            for n in [1, 2, 3, 4, 8] {
                let r = timing(&dir, n, threads, seconds)?;
                if json {
                    super::json_line(out, &r)?;
                } else {
                    writeln!(
                        out,
                        "{:<11} {:>6} {:>7}  {:>12.2}  {:>17.2}  {:>12}  {:>14}  {:>11.2}",
                        r.case,
                        r.bodies,
                        r.threads,
                        r.frame_ms_p50,
                        r.frame_ms_p99_max,
                        r.missed_ticks,
                        r.deadline_stops,
                        r.residual_mm_rms_max
                    )?;
                }
            }
        }
        for gate in [true, false] {
            let r = label_swap(&dir, 0.3, gate)?;
            if json {
                super::json_line(out, &r)?;
            } else {
                writeln!(
                    out,
                    "label swap, {} markers for {} s, bodies {} m apart, identity gate {}: {} of {} frames pulled more than {PULL_LIMIT_M} m towards the other, at most {:.3} m; {} samples gated",
                    r.markers_swapped, r.swap_secs, r.apart_m, if gate { "on" } else { "off" },
                    r.frames_pulled, r.frames, r.worst_pull_m, r.identity_gated
                )?;
            }
        }
        match real_pair(data, &dir)? {
            Some(r) if json => super::json_line(out, &r)?,
            Some(r) => writeln!(
                out,
                "two real takes in one ({} as A, {} as B, 3 m apart): samples fed A {} (alone {}), B {} (alone {}); residual RMS A {:.2} mm (alone {:.2}), B {:.2} mm (alone {:.2})",
                r.takes[0], r.takes[1], r.samples_pair[0], r.samples_alone[0], r.samples_pair[1],
                r.samples_alone[1], r.residual_mm_pair[0], r.residual_mm_alone[0],
                r.residual_mm_pair[1], r.residual_mm_alone[1]
            )?,
            None => writeln!(out, "two real takes in one: skipped ({} lacks c3d/real/)", data.display())?,
        }
        Ok(())
    })();
    std::fs::remove_dir_all(&dir)?;
    result
}
