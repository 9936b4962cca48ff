//! `rigless listen URL`: prints what an input decodes, one line (or JSON object) per
//! packet, through the same input adapter a stage uses.

use super::{check_seconds, ctrl_c_flag};
use anyhow::{bail, Context, Result};
use glam::{DQuat, DVec3};
use rigless::character::procedural::hand_skeleton;
use rigless::character::skeleton::Skeleton;
use rigless::input::config::InputConfig;
use rigless::input::glove::HandMap;
use rigless::input::{Input, InputFrame, InputSink, OpenContext};
use rigless::protocol::glove::{buttons, GloveReading};
use rigless::runtime::clock::SystemClock;
use serde_json::{json, Value};
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

#[derive(clap::Args)]
pub struct ListenArgs {
    /// The input URL, e.g. osc://127.0.0.1:9000.
    url: String,
    /// One JSON object per packet.
    #[arg(long)]
    json: bool,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    seconds: Option<f64>,
    /// Stop after this many packets.
    #[arg(long)]
    packets: Option<u64>,
    /// Metres per sender unit (0.001 for a millimetre sender; osc:// only).
    #[arg(long, default_value_t = 1.0)]
    scale: f64,
    /// The sender's up axis is Z (converted to the world's Y up; osc:// only).
    #[arg(long)]
    z_up: bool,
}

pub fn run(a: ListenArgs) -> Result<()> {
    check_seconds(a.seconds)?;
    if !(a.scale.is_finite() && a.scale > 0.0) {
        bail!(
            "--scale must be a positive number of metres per unit, got {:?}",
            a.scale
        );
    }
    let cfg = InputConfig::from_url(&a.url)?.with_sender_units(a.scale, a.z_up);
    // A glove poses the procedural hand's fingers, wrist at rest: its skeleton alone,
    // so that the socket is bound at once (packets sent before are lost).
    let skeleton = hand_skeleton();
    let input = Input::open(
        &cfg,
        &OpenContext {
            base_dir: std::path::Path::new("."),
            markers: None,
            skeleton: Some(&skeleton),
            procedural: None,
            subject: &rigless::markers::index::SubjectFilter::One,
            actors: None,
        },
    )?;
    match input.local_addr() {
        Some(bound) => eprintln!("listening on {} (bound {bound}); Ctrl-C stops", a.url),
        None => eprintln!("{}; Ctrl-C stops", input.opened()),
    }
    let stop = ctrl_c_flag()?;
    if let Some(s) = a.seconds {
        let stop = Arc::clone(&stop);
        std::thread::Builder::new()
            .name("listen-timer".into())
            .spawn(move || {
                std::thread::sleep(std::time::Duration::from_secs_f64(s));
                stop.store(true, Ordering::Relaxed);
            })
            .context("starting the --seconds timer")?;
    }
    let mut printer = Printer {
        out: std::io::stdout().lock(),
        json: a.json,
        packets: a.packets,
        seen: 0,
        write_error: None,
        stop: Arc::clone(&stop),
        skeleton: &skeleton,
    };
    let summary = input.run(&SystemClock::new(), 0.0, &stop, &mut printer)?;
    if let Some(e) = printer.write_error {
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            return Err(e.into());
        }
    }
    eprintln!("{summary}");
    Ok(())
}

/// Prints each packet; stops after `packets` or on a write error.
struct Printer<'a, W: Write> {
    out: W,
    json: bool,
    packets: Option<u64>,
    seen: u64,
    write_error: Option<std::io::Error>,
    stop: Arc<AtomicBool>,
    /// The skeleton a glove poses.
    skeleton: &'a Skeleton,
}

/// A marker as printed: name, position (metres, Y up) and whether it is occluded.
type Shown<'a> = (&'a str, DVec3, bool);

impl<W: Write> Printer<'_, W> {
    fn print(
        &mut self,
        recv: f64,
        source: Option<f64>,
        frame: Option<i64>,
        markers: &[Shown<'_>],
        extra: Option<(&str, Value)>,
    ) -> bool {
        let line = if self.json {
            let mut v = json!({
                "receive_unix_s": recv,
                "source_time_s": source,
                "frame": frame,
                "markers": markers.iter().map(|(name, p, occluded)| json!({
                    "name": name,
                    "position_m": if *occluded { Value::Null } else { json!(p.to_array()) },
                    "occluded": occluded,
                })).collect::<Vec<_>>(),
            });
            if let Some((key, value)) = extra {
                v[key] = value;
            }
            v.to_string()
        } else if let Some((key, value)) = extra {
            format!("recv {recv:.6}  {key} {value}")
        } else {
            let text: Vec<String> = markers
                .iter()
                .map(|(name, p, occluded)| {
                    if *occluded {
                        format!("{name} occluded")
                    } else {
                        format!("{name} ({:.4}, {:.4}, {:.4})", p.x, p.y, p.z)
                    }
                })
                .collect();
            format!(
                "recv {recv:.6}  source {}  frame {}  {} markers: {}",
                source.map_or("-".into(), |t| format!("{t:.6}")),
                frame.map_or("-".into(), |n| n.to_string()),
                markers.len(),
                text.join(", ")
            )
        };
        if let Err(e) = writeln!(self.out, "{line}").and_then(|_| self.out.flush()) {
            self.write_error = Some(e);
            return false;
        }
        self.seen += 1;
        if self.packets.is_some_and(|n| self.seen >= n) {
            self.stop.store(true, Ordering::Relaxed);
        }
        true
    }
}

impl<W: Write> InputSink for Printer<'_, W> {
    fn frame(&mut self, f: &InputFrame<'_>) -> bool {
        let shown: Vec<Shown<'_>> = f
            .samples
            .iter()
            .map(|s| {
                let name = f.names.get(s.marker as usize).map_or("?", String::as_str);
                (name, s.position_m, s.occluded)
            })
            .collect();
        self.print(f.receive_unix_s, f.source_time_s, f.frame, &shown, None)
    }

    fn glove(&mut self, recv: f64, r: &GloveReading, map: &HandMap) -> bool {
        let sk = self.skeleton;
        let mut local = vec![DQuat::IDENTITY; sk.len()];
        let (mut world_r, mut world_p) = (local.clone(), vec![DVec3::ZERO; sk.len()]);
        map.local_rotations(r, &mut local);
        sk.forward(&local, DVec3::ZERO, &mut world_r, &mut world_p);
        let shown: Vec<Shown<'_>> = map
            .joints()
            .iter()
            .flat_map(|f| [f[0], f[1], f[2], f[2] + 1])
            .filter(|&j| j < sk.len())
            .map(|j| (sk.joints[j].name.as_str(), world_p[j], false))
            .collect();
        let max = f64::from(map.max_value());
        let frac = |v: &[Option<u32>]| -> Vec<Option<f64>> {
            v.iter().map(|x| x.map(|x| f64::from(x) / max)).collect()
        };
        let pressed: Vec<&str> = (0..8)
            .filter(|b| r.buttons & (1 << b) != 0)
            .map(|b| buttons::NAMES[b])
            .collect();
        let glove = json!({
            "curl": frac(&r.curl),
            "splay": frac(&r.splay),
            "joystick": frac(&r.joystick),
            "trigger": r.trigger.map(|x| f64::from(x) / max),
            "buttons": pressed,
        });
        self.print(recv, None, None, &shown, Some(("glove", glove)))
    }
}
