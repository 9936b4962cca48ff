//! Input adapters: every kind of input is opened from its config section
//! ([`Input::open`]: binds its socket, opens its port, loads its recording, resolves its
//! marker names) and then runs on its own thread ([`Input::run`]): it receives, reads or
//! plays its packets, decodes them with `protocol/`, converts units once, and hands each
//! packet's [`MarkerSample`]s, marker indices already resolved, to an [`InputSink`]: the
//! stage's bounded channel ([`ChannelSink`], which also judges the input's source clock
//! with a [`source_clock::SourceClock`]) or `rigless listen`'s printer. [`Input`] is
//! the one dispatch over input kinds in the crate; a new protocol is a codec in
//! `protocol/`, an adapter file here and a variant of [`config::InputConfig`].

pub mod config;
pub mod glove;
pub mod natnet;
pub mod osc;
pub mod replay;
pub mod source_clock;
pub mod synthetic;
pub mod udp;
pub mod vrpn;

use crate::character::procedural::Character;
use crate::character::skeleton::Skeleton;
use crate::markers::index::{ActorLabels, MarkerIndex, SubjectFilter};
use crate::markers::MarkerSample;
use crate::protocol::glove::GloveReading;
use crate::rig::bind::Rig;
use crate::runtime::clock::Clock;
use crate::runtime::said::Throttle;
use crate::runtime::slot::PinSlot;
use config::InputConfig;
use crossbeam_channel::{Sender, TrySendError};
use source_clock::{ClockEvent, SourceClock, SourceClockParams, Stamp};
use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// Most distinct marker names a growing index (`rigless listen`) keeps: names come from
/// the network, so their number is bounded.
pub const MAX_LISTEN_NAMES: usize = 4096;

/// What an input needs to know of the stage when it opens.
#[derive(Clone, Copy)]
pub struct OpenContext<'a> {
    /// Folder that relative recording paths are resolved against.
    pub base_dir: &'a Path,
    /// The character's marker names; `None` (`rigless listen`) gives every name the
    /// input meets an index of its own.
    pub markers: Option<&'a [String]>,
    /// The skeleton a data glove poses.
    pub skeleton: Option<&'a Skeleton>,
    /// The procedural character a synthetic input plays.
    pub procedural: Option<&'a Arc<Character>>,
    /// Whose labels feed the character's markers (`[character] subject`).
    pub subject: &'a SubjectFilter,
    /// A stage of several actors: each one's markers and claim (then `markers` are all
    /// of theirs, by stage index, and `subject` is not used).
    pub actors: Option<&'a [ActorLabels]>,
}

impl OpenContext<'_> {
    /// The index an input resolves names with.
    fn index(&self) -> MarkerIndex {
        match (self.actors, self.markers) {
            (Some(actors), _) => MarkerIndex::for_actors(actors),
            (None, Some(names)) => MarkerIndex::fixed_for(names, self.subject.clone()),
            (None, None) => MarkerIndex::growing(MAX_LISTEN_NAMES),
        }
    }
}

/// Why an input could not open or run.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    #[error("{url}: {source}")]
    Url {
        url: String,
        source: config::InputUrlError,
    },
    #[error("binding {url}: {source}")]
    Bind { url: String, source: std::io::Error },
    #[error(transparent)]
    Recording(#[from] crate::replay::recording::RecordingError),
    #[error("no bundled session {name:?}")]
    NoSuchSession { name: String },
    #[error("a replay input needs a session or a path")]
    NoRecording,
    #[error("{name}: none of its {labels} labels is one of the character's markers ({markers})")]
    NoMatchingLabel {
        name: String,
        labels: usize,
        markers: String,
    },
    #[error("a synthetic input needs a procedural character")]
    NeedsProcedural,
    #[error("{url}: a glove input needs a character with a skeleton")]
    NeedsSkeleton { url: String },
    #[error("{url}: the glove cannot drive this character:{}", lines(problems))]
    GloveMap {
        url: String,
        problems: Vec<glove::GloveMapError>,
    },
    #[error("{url}: cannot open its command socket: {source}")]
    CommandSocket { url: String, source: std::io::Error },
    #[error("{url}: cannot set up its socket to receive: {source}")]
    Receive { url: String, source: std::io::Error },
}

/// An input's closing summary, with what its index refused of other subjects' labels
/// ([`MarkerIndex::refused_text`]) when it refused any.
fn with_refused(summary: String, index: &MarkerIndex) -> String {
    match index.refused_text() {
        Some(r) => format!("{summary}; {r}"),
        None => summary,
    }
}

/// Each item on a line of its own, indented.
fn lines(items: &[impl std::fmt::Display]) -> String {
    items.iter().map(|i| format!("\n  {i}")).collect()
}

/// One packet of an input (or one frame of a recording), decoded.
#[derive(Clone, Copy, Debug)]
pub struct InputFrame<'a> {
    /// When it arrived (or was due, for a recording), seconds on the stage's clock.
    pub time_s: f64,
    /// When it arrived, seconds since the Unix epoch.
    pub receive_unix_s: f64,
    /// The sender's time of the packet, seconds, when the protocol has one.
    pub source_time_s: Option<f64>,
    /// The sender's frame number, when the protocol has one.
    pub frame: Option<i64>,
    /// Its markers, indices resolved (markers with no index are left out).
    pub samples: &'a [MarkerSample],
    /// Marker names by index (the character's, or every name met so far).
    pub names: &'a [String],
}

/// Where an input's packets go.
pub trait InputSink {
    /// One packet's samples. Returns false when nobody takes them any more: the input
    /// then ends.
    fn frame(&mut self, frame: &InputFrame<'_>) -> bool;
    /// One data-glove reading received at `receive_unix_s`, with the glove's map onto
    /// the character's joints. Returns false as [`Self::frame`] does.
    fn glove(&mut self, receive_unix_s: f64, reading: &GloveReading, map: &glove::HandMap) -> bool;
}

/// An opened input, ready to run.
pub struct Input {
    kind: &'static str,
    source: Source,
}

enum Source {
    Osc(osc::OscInput),
    NatNet(natnet::NatNetInput),
    Vrpn(vrpn::VrpnInput),
    Glove(Box<glove::GloveInput>),
    Replay(replay::ReplayInput),
    Synthetic(synthetic::SyntheticInput),
}

impl Input {
    /// Opens the input `cfg` describes: binds, opens or loads what it needs and resolves
    /// its names, so that what can fail fails here, before the stage runs.
    pub fn open(cfg: &InputConfig, ctx: &OpenContext<'_>) -> Result<Self, InputError> {
        let source = match cfg {
            InputConfig::Osc(c) => Source::Osc(osc::OscInput::open(c, ctx.index())?),
            InputConfig::NatNet(c) => Source::NatNet(natnet::NatNetInput::open(c, ctx.index())?),
            InputConfig::Vrpn(c) => Source::Vrpn(vrpn::VrpnInput::open(c, ctx.index())?),
            InputConfig::Glove(c) => {
                Source::Glove(Box::new(glove::GloveInput::open(c, ctx.skeleton)?))
            }
            InputConfig::Replay(c) => Source::Replay(replay::ReplayInput::open(c, ctx)?),
            InputConfig::Synthetic(c) => {
                Source::Synthetic(synthetic::SyntheticInput::open(c, ctx.procedural)?)
            }
        };
        Ok(Self {
            kind: cfg.kind(),
            source,
        })
    }

    /// The input's kind, as its config's `type` names it.
    pub fn kind(&self) -> &'static str {
        self.kind
    }

    /// What was opened, for the user: `osc input listening on udp://ADDR`, `replaying
    /// NAME: ...`.
    pub fn opened(&self) -> String {
        match &self.source {
            Source::Osc(i) => i.opened(),
            Source::NatNet(i) => i.opened(),
            Source::Vrpn(i) => i.opened(),
            Source::Glove(i) => i.opened(),
            Source::Replay(i) => i.opened(),
            Source::Synthetic(i) => i.opened(),
        }
    }

    /// What the user should know before it runs (labels ignored, markers no label
    /// feeds, what a file reader tolerated).
    pub fn warnings(&self) -> Vec<String> {
        match &self.source {
            Source::Replay(i) => i.warnings(),
            _ => Vec::new(),
        }
    }

    /// A recording's labels that feed a marker, and those ignored (`None` for inputs
    /// whose names arrive with the packets).
    pub fn label_counts(&self) -> Option<(usize, usize)> {
        match &self.source {
            Source::Replay(i) => Some(i.label_counts()),
            _ => None,
        }
    }

    /// The local address of a socket input.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        match &self.source {
            Source::Osc(i) => i.local_addr(),
            Source::NatNet(i) => i.local_addr(),
            _ => None,
        }
    }

    /// How long a finite input plays, seconds (its frames over its rate, at its speed;
    /// `None`: it runs until stopped).
    pub fn duration_s(&self) -> Option<f64> {
        match &self.source {
            Source::Replay(i) => i.duration_s(),
            Source::Synthetic(i) => i.duration_s(),
            _ => None,
        }
    }

    /// Whether the input paces itself on the stage's clock (recordings and the synthetic
    /// source) rather than waiting on a socket or a port.
    pub fn is_paced(&self) -> bool {
        matches!(self.source, Source::Replay(_) | Source::Synthetic(_))
    }

    /// Runs the input on the calling thread until `stop` is set, it ends, or the sink
    /// refuses a packet (which also sets `stop`); an input that paces itself sends its
    /// first frame at `start_s` on `clock`. Returns a line on what it received.
    pub fn run(
        self,
        clock: &dyn Clock,
        start_s: f64,
        stop: &AtomicBool,
        sink: &mut dyn InputSink,
    ) -> Result<String, InputError> {
        match self.source {
            Source::Osc(i) => Ok(i.run(clock, stop, sink)),
            Source::NatNet(i) => i.run(clock, stop, sink),
            Source::Vrpn(i) => Ok(i.run(clock, stop, sink)),
            Source::Glove(i) => Ok(i.run(stop, sink)),
            Source::Replay(i) => Ok(i.run(clock, start_s, stop, sink)),
            Source::Synthetic(i) => Ok(i.run(clock, start_s, stop, sink)),
        }
    }
}

/// What a running input has done (shared with the status line and the Rerun sink).
#[derive(Debug, Default)]
pub struct SourceCounters {
    /// Frames (packets) received.
    pub frames: AtomicU64,
    /// Samples sent on.
    pub samples: AtomicU64,
    /// Samples dropped because the channel was full.
    pub dropped: AtomicU64,
    /// Times the source clock jumped (episodes: a jump while it is already untrusted is
    /// part of the same one).
    pub clock_jumps: AtomicU64,
    /// Packets whose source time was not trusted (stamped from the receive clock).
    pub clock_untrusted: AtomicU64,
    /// When the newest frame arrived, seconds on the stage's clock (`f64` bits).
    last_frame_s: AtomicU64,
    /// The longest interval between consecutive frames since it was last taken, seconds
    /// (`f64` bits; non-negative, so the bits order as the values do).
    longest_interval_s: AtomicU64,
}

impl SourceCounters {
    /// Counts a frame that arrived at `now_s` (seconds on any clock the source keeps
    /// using: only differences are kept).
    pub fn count_frame(&self, now_s: f64) {
        let last = f64::from_bits(self.last_frame_s.swap(now_s.to_bits(), Ordering::Relaxed));
        if self.frames.fetch_add(1, Ordering::Relaxed) > 0 {
            let interval = (now_s - last).max(0.0);
            self.longest_interval_s
                .fetch_max(interval.to_bits(), Ordering::Relaxed);
        }
    }

    /// The longest interval between consecutive frames since the last call, seconds (0
    /// when fewer than two frames arrived).
    pub fn take_longest_interval_s(&self) -> f64 {
        f64::from_bits(self.longest_interval_s.swap(0, Ordering::Relaxed))
    }
}

/// What a packet input has received (monotonic).
#[derive(Debug, Default)]
pub struct PacketStats {
    pub packets: AtomicU64,
    pub bytes: AtomicU64,
    /// Packets that did not decode, and receive errors.
    pub decode_errors: AtomicU64,
    /// f64 bits of the Unix time of the newest packet (0 before any).
    pub last_seen_unix_bits: AtomicU64,
}

impl PacketStats {
    /// Counts one received packet.
    pub fn received(&self, len: usize, unix_s: f64) {
        self.packets.fetch_add(1, Ordering::Relaxed);
        self.bytes.fetch_add(len as u64, Ordering::Relaxed);
        self.last_seen_unix_bits
            .store(unix_s.to_bits(), Ordering::Relaxed);
    }

    /// Counts a packet that did not decode, or a receive error.
    pub fn error(&self) {
        self.decode_errors.fetch_add(1, Ordering::Relaxed);
    }

    pub fn last_seen_unix_s(&self) -> f64 {
        f64::from_bits(self.last_seen_unix_bits.load(Ordering::Relaxed))
    }
}

impl std::fmt::Display for PacketStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} packets, {} bytes, {} not decodable",
            self.packets.load(Ordering::Relaxed),
            self.bytes.load(Ordering::Relaxed),
            self.decode_errors.load(Ordering::Relaxed)
        )
    }
}

/// Joint angles a data glove imposes on the posture, through the stage's pin slot.
pub struct PinTarget {
    /// Where the loop reads the angles.
    pub slot: Arc<PinSlot>,
    /// The rig whose posture parameters they are.
    pub rig: Arc<Rig>,
}

/// The stage's sink: samples go into the bounded channel without blocking (a full
/// channel drops and counts), glove readings into the pin slot; every frame is counted.
/// A packet's source time passes its input's [`SourceClock`] first: while that clock is
/// not trusted, the samples carry a source time derived from their receive time.
pub struct ChannelSink {
    /// One channel per actor (one for a stage of one), and each actor's first marker's
    /// stage index (`starts[0] = 0`): a sample goes to its actor's channel with the
    /// actor's own marker index.
    tx: Vec<Sender<MarkerSample>>,
    starts: Vec<u32>,
    counters: Arc<SourceCounters>,
    pins: Option<PinTarget>,
    clock: SourceClock,
    /// Lines about the source clock jumping, and about it being steady again: each at
    /// most once per [`CLOCK_LINE_INTERVAL_S`] of receive time, the rest counted.
    jump_lines: Throttle,
    steady_lines: Throttle,
    /// The input, as logs name it.
    name: String,
}

impl ChannelSink {
    pub fn new(
        tx: Sender<MarkerSample>,
        counters: Arc<SourceCounters>,
        pins: Option<PinTarget>,
    ) -> Self {
        Self {
            tx: vec![tx],
            starts: vec![0],
            counters,
            pins,
            clock: SourceClock::new(SourceClockParams::default()),
            jump_lines: Throttle::new(CLOCK_LINE_INTERVAL_S),
            steady_lines: Throttle::new(CLOCK_LINE_INTERVAL_S),
            name: "input".into(),
        }
    }

    /// Routes samples to several actors: `tx[a]` takes the markers from `starts[a]` up
    /// to the next actor's start (stage indices, [`MarkerIndex::for_actors`]), each
    /// sent with the actor's own index. `starts` rises from 0, one per channel.
    pub fn routed(mut self, tx: Vec<Sender<MarkerSample>>, starts: Vec<u32>) -> Self {
        debug_assert!(tx.len() == starts.len() && starts.first() == Some(&0));
        self.tx = tx;
        self.starts = starts;
        self
    }

    /// Names the input in what the sink logs (`input 0 (osc)`).
    pub fn named(mut self, name: String) -> Self {
        self.name = name;
        self
    }

    /// Judges a packet's source time; returns the one its samples carry when it is not
    /// their own. Logs once per episode.
    fn source_time(&mut self, frame: &InputFrame<'_>) -> Option<f64> {
        let source = frame.source_time_s?;
        let stamp = self.clock.stamp(frame.time_s, source);
        let c = &self.counters;
        match stamp.event {
            Some(ClockEvent::Jumped {
                source_time_s,
                offset_change_s,
            }) => {
                c.clock_jumps.fetch_add(1, Ordering::Relaxed);
                let Some(unsaid) = self.jump_lines.hit(frame.time_s) else {
                    return self.untrusted(stamp);
                };
                let name = &self.name;
                let unsaid = unsaid_note(unsaid);
                if stamp.trusted {
                    tracing::warn!(
                        input = %name, source_time_s, offset_change_s,
                        "{name}: the source clock jumped before it settled; taking its new time{unsaid}"
                    );
                } else {
                    tracing::warn!(
                        input = %name, source_time_s, offset_change_s,
                        "{name}: the source clock jumped (source time {source_time_s} s, {offset_change_s:+} s against the receive clock); its samples carry receive times until it is steady again{unsaid}"
                    );
                }
            }
            Some(ClockEvent::Steady { untrusted_packets }) => {
                if let Some(unsaid) = self.steady_lines.hit(frame.time_s) {
                    let (name, unsaid) = (&self.name, unsaid_note(unsaid));
                    tracing::info!(
                        input = %name, untrusted_packets,
                        "{name}: the source clock is steady again after {untrusted_packets} packets{unsaid}"
                    );
                }
            }
            None => {}
        }
        self.untrusted(stamp)
    }

    /// The source time to stamp the samples with when the packet's own is not trusted
    /// (counted).
    fn untrusted(&self, stamp: Stamp) -> Option<f64> {
        if stamp.trusted {
            return None;
        }
        self.counters
            .clock_untrusted
            .fetch_add(1, Ordering::Relaxed);
        Some(stamp.source_time_s)
    }
}

/// Seconds of receive time between two lines of a kind about an input's source clock.
pub const CLOCK_LINE_INTERVAL_S: f64 = 5.0;

/// `" (N more since the last line)"`, or nothing.
fn unsaid_note(unsaid: u64) -> String {
    if unsaid == 0 {
        String::new()
    } else {
        format!(" ({unsaid} more since the last line)")
    }
}

impl InputSink for ChannelSink {
    fn frame(&mut self, frame: &InputFrame<'_>) -> bool {
        self.counters.count_frame(frame.time_s);
        let replaced = self.source_time(frame);
        let c = &self.counters;
        for s in frame.samples {
            let mut s = *s;
            if let Some(t) = replaced {
                s.source_time_s = t;
            }
            // The last actor whose first marker is at or before this one's (a stage of
            // one: the first).
            let a = self
                .starts
                .partition_point(|&start| start <= s.marker)
                .max(1)
                - 1;
            s.marker -= self.starts[a];
            match self.tx[a].try_send(s) {
                Ok(()) => c.samples.fetch_add(1, Ordering::Relaxed),
                Err(TrySendError::Full(_)) => c.dropped.fetch_add(1, Ordering::Relaxed),
                Err(TrySendError::Disconnected(_)) => return false,
            };
        }
        true
    }

    fn glove(&mut self, receive_unix_s: f64, reading: &GloveReading, map: &glove::HandMap) -> bool {
        if let Some(PinTarget { slot, rig }) = &self.pins {
            let first = |j: usize| rig.ik.angle_params(j);
            slot.write(|pins| map.write_pins(reading, &first, pins));
        }
        self.counters.count_frame(receive_unix_s);
        true
    }
}

/// A fixed-rate sending loop for inputs that pace themselves: frame `n` (counting across
/// loops) is due at `start_s + n · period_s` on `clock`, where `emit(n, t)` sends it. It
/// ends after `frames` frames unless `looping`, when `stop` is set, or when `emit`
/// returns false.
#[allow(clippy::too_many_arguments)]
pub fn play_paced(
    clock: &dyn Clock,
    start_s: f64,
    period_s: f64,
    frames: usize,
    looping: bool,
    stop: &AtomicBool,
    emit: &mut dyn FnMut(usize, f64) -> bool,
) {
    let mut n = 0usize;
    while frames > 0 && (looping || n < frames) {
        let t = start_s + n as f64 * period_s;
        clock.sleep_until(t);
        if stop.load(Ordering::Relaxed) || !emit(n, t) {
            break;
        }
        n += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_channel_drops_and_counts_and_a_closed_one_ends_the_input() {
        let (tx, rx) = crossbeam_channel::bounded(2);
        let counters = Arc::new(SourceCounters::default());
        let mut sink = ChannelSink::new(tx, Arc::clone(&counters), None);
        let sample = |k: u32| MarkerSample {
            marker: k,
            time_s: 0.0,
            source_time_s: 0.0,
            position_m: glam::DVec3::ZERO,
            occluded: false,
        };
        let samples = [sample(0), sample(1), sample(2)];
        let frame = |t: f64| InputFrame {
            time_s: t,
            receive_unix_s: 0.0,
            source_time_s: None,
            frame: None,
            samples: &samples,
            names: &[],
        };
        assert!(sink.frame(&frame(1.0)));
        assert_eq!(counters.samples.load(Ordering::Relaxed), 2);
        assert_eq!(counters.dropped.load(Ordering::Relaxed), 1);
        assert_eq!(rx.try_recv().map(|s| s.marker), Ok(0));
        assert!(sink.frame(&frame(1.25)));
        assert_eq!(counters.take_longest_interval_s(), 0.25);
        drop(rx);
        assert!(!sink.frame(&frame(1.5)), "the receiver is gone");
        assert_eq!(counters.frames.load(Ordering::Relaxed), 3);
    }

    #[test]
    fn a_clock_that_never_settles_is_said_once_per_interval_not_per_packet() {
        // Time tags alternating between 0 and 1e6 s, 1000 packets a second for 10 s: a
        // jump every packet, said at most once per CLOCK_LINE_INTERVAL_S.
        let (tx, rx) = crossbeam_channel::bounded(16);
        let counters = Arc::new(SourceCounters::default());
        let mut sink = ChannelSink::new(tx, Arc::clone(&counters), None).named("input 0".into());
        let samples = [MarkerSample {
            marker: 0,
            time_s: 0.0,
            source_time_s: 0.0,
            position_m: glam::DVec3::ZERO,
            occluded: false,
        }];
        let ((), logs) = crate::runtime::logs::captured(|| {
            for n in 0..10_000 {
                let source = if n % 2 == 0 { 0.0 } else { 1e6 };
                assert!(sink.frame(&InputFrame {
                    time_s: n as f64 * 1e-3,
                    receive_unix_s: 0.0,
                    source_time_s: Some(source),
                    frame: None,
                    samples: &samples,
                    names: &[],
                }));
                while rx.try_recv().is_ok() {}
            }
        });
        let jumps = counters.clock_jumps.load(Ordering::Relaxed);
        assert!(jumps >= 9_990, "{jumps}");
        // 10 s of receive time: lines at 0 s and 5 s (the second saying how many were not).
        let lines: Vec<&str> = logs.lines().collect();
        assert_eq!(lines.len(), 2, "{logs}");
        assert!(lines[1].contains("more since the last line"), "{logs}");
    }

    #[test]
    fn a_jumping_source_clock_is_replaced_in_the_samples_and_counted() {
        let (tx, rx) = crossbeam_channel::bounded(64);
        let counters = Arc::new(SourceCounters::default());
        let mut sink = ChannelSink::new(tx, Arc::clone(&counters), None).named("input 0".into());
        // Packet n received at n/4 s, its source clock 1000 s ahead; packet 12 carries
        // 2085978495 s (an OSC time tag of 0xFFFFFFFF s).
        let source = |n: usize| {
            if n == 12 {
                2_085_978_495.0
            } else {
                1000.0 + n as f64 * 0.25
            }
        };
        let mut got = Vec::new();
        let ((), logs) = crate::runtime::logs::captured(|| {
            for n in 0..30 {
                let t = n as f64 * 0.25;
                let samples = [MarkerSample {
                    marker: 0,
                    time_s: t,
                    source_time_s: source(n),
                    position_m: glam::DVec3::ZERO,
                    occluded: false,
                }];
                assert!(sink.frame(&InputFrame {
                    time_s: t,
                    receive_unix_s: 0.0,
                    source_time_s: Some(source(n)),
                    frame: None,
                    samples: &samples,
                    names: &[],
                }));
                got.push(rx.try_recv().unwrap().source_time_s);
            }
        });
        // Every sample carries 1000 + n/4, the bad one included: packets 12 to 21 (the
        // bad one and the nine until ten agree) are stamped receive + 1000, exactly that.
        let want: Vec<f64> = (0..30).map(|n| 1000.0 + n as f64 * 0.25).collect();
        assert_eq!(got, want);
        assert_eq!(counters.clock_jumps.load(Ordering::Relaxed), 1);
        assert_eq!(counters.clock_untrusted.load(Ordering::Relaxed), 10);
        // Logged once per episode: when it jumped, and when it was steady again.
        let lines: Vec<&str> = logs.lines().collect();
        assert_eq!(lines.len(), 2, "{logs}");
        assert!(
            lines[0].contains("WARN") && lines[0].contains("input 0: the source clock jumped"),
            "{logs}"
        );
        assert!(
            lines[1].contains("INFO") && lines[1].contains("steady again after 10 packets"),
            "{logs}"
        );
    }
}
