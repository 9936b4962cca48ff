//! The synthetic input: a session of the stage's procedural character
//! ([`crate::character::session`]) played live at its own rate on the stage's clock.

use super::config::SyntheticInputConfig;
use super::{play_paced, InputError, InputFrame, InputSink};
use crate::character::body::BodyMotion;
use crate::character::demo::Motion;
use crate::character::procedural::Character;
use crate::character::session::{SyntheticParams, SyntheticSession};
use crate::runtime::clock::Clock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// An opened synthetic input: a session of the stage's procedural character.
pub struct SyntheticInput {
    session: SyntheticSession,
    looping: bool,
}

impl SyntheticInput {
    /// A session of `character` as `cfg` describes it.
    pub fn open(
        cfg: &SyntheticInputConfig,
        character: Option<&Arc<Character>>,
    ) -> Result<Self, InputError> {
        let ch = character.ok_or(InputError::NeedsProcedural)?;
        let motion = match (ch.name.as_str(), cfg.motion.as_deref()) {
            ("body", Some("reach")) => Motion::Body(BodyMotion::Reach),
            ("body", Some("rom")) => Motion::Body(BodyMotion::RangeOfMotion),
            ("body", _) => Motion::Body(BodyMotion::Walk),
            _ => Motion::FingerPlay,
        };
        let session = SyntheticSession::new(
            Arc::clone(ch),
            motion,
            SyntheticParams {
                rate_hz: cfg.rate_hz,
                duration_secs: cfg.session_secs,
                noise_m: cfg.noise_mm * 1e-3,
                gap_fraction: cfg.gap_percent / 100.0,
                seed: cfg.seed,
                ..SyntheticParams::default()
            },
        );
        Ok(Self {
            session,
            looping: cfg.looping,
        })
    }

    /// `synthetic input: the CHARACTER's MOTION, N s at R Hz[, looping]`.
    pub fn opened(&self) -> String {
        let p = self.session.params();
        format!(
            "synthetic input: the {}'s {}, {} s at {} Hz{}",
            self.session.character().name,
            self.session.motion().name(),
            p.duration_secs,
            p.rate_hz,
            if self.looping { ", looping" } else { "" }
        )
    }

    /// How long it plays, seconds: the session's length (`None` when looping).
    pub fn duration_s(&self) -> Option<f64> {
        (!self.looping).then(|| self.session.params().duration_secs)
    }

    /// Plays the session in real time on `clock` from `start_s` to its end (forever
    /// when looping) or until `stop` is set.
    pub fn run(
        mut self,
        clock: &dyn Clock,
        start_s: f64,
        stop: &AtomicBool,
        sink: &mut dyn InputSink,
    ) -> String {
        let frames = self.session.frames().max(1);
        let rate_hz = self.session.params().rate_hz;
        let period = 1.0 / rate_hz;
        let names: Vec<String> = self
            .session
            .character()
            .markers
            .iter()
            .map(|m| m.name.clone())
            .collect();
        let mut batch = Vec::new();
        let mut sent = 0usize;
        play_paced(
            clock,
            start_s,
            period,
            frames,
            self.looping,
            stop,
            &mut |n, t| {
                batch.clear();
                self.session.frame(n % frames, t, &mut batch);
                // The source clock runs on across loops, as a recording's does (a clock
                // that went back at every loop would be a jump each time).
                let source = n as f64 / rate_hz;
                for s in &mut batch {
                    s.source_time_s = source;
                }
                sent += 1;
                let taken = sink.frame(&InputFrame {
                    time_s: t,
                    receive_unix_s: clock.unix_s(t),
                    source_time_s: Some(source),
                    frame: Some(n as i64),
                    samples: &batch,
                    names: &names,
                });
                if !taken {
                    stop.store(true, Ordering::Relaxed);
                }
                taken
            },
        );
        format!("{sent} synthetic frames played")
    }
}
