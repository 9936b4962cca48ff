//! Whether an input's source clock can be trusted: [`SourceClock`] compares each packet's
//! source time (the sender's timestamp: an OSC time tag, NatNet's timestamp, a VRPN
//! report's time) with its receive time on the stage's clock. While their offset holds
//! steady the source time passes through; when it jumps (the offset changes by more than
//! [`SourceClockParams::max_jump_s`] from one packet to the next, the source time goes
//! backwards beyond [`SourceClockParams::backwards_tolerance_s`], or it is not a finite
//! number) the source clock is untrusted, and its packets are stamped with their receive
//! time plus the last trusted offset, until [`SourceClockParams::steady_packets`] packets
//! in a row agree again. A sender's one bad time tag then costs nothing downstream.
//!
//! A pure type: times are passed in. The stage's [`super::ChannelSink`] keeps one per
//! input, so every input's samples pass through it.

/// How much a source clock may move before it is untrusted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SourceClockParams {
    /// Largest change of the source-minus-receive offset from one packet to the next that
    /// is still the same clock, seconds. Network and scheduling jitter are milliseconds;
    /// a replay faster or slower than real time drifts a period's fraction per packet.
    pub max_jump_s: f64,
    /// How far a source time may go back from the previous packet's (reordered
    /// datagrams), seconds.
    pub backwards_tolerance_s: f64,
    /// Consecutive agreeing packets before an untrusted clock is trusted again, and
    /// before a new input's clock counts as established.
    pub steady_packets: u32,
}

impl Default for SourceClockParams {
    fn default() -> Self {
        Self {
            max_jump_s: 1.0,
            backwards_tolerance_s: 0.05,
            steady_packets: 10,
        }
    }
}

/// What happened to the source clock with a packet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ClockEvent {
    /// It jumped (this packet starts an episode). `offset_change_s` is the change from
    /// the previous packet's offset (NaN when the source time is not a number).
    Jumped {
        source_time_s: f64,
        offset_change_s: f64,
    },
    /// It is trusted again after an episode of `untrusted_packets` packets.
    Steady { untrusted_packets: u64 },
}

/// A packet's source time as the clock judged it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stamp {
    /// The source time to use: the packet's own, or its receive time plus the last
    /// trusted offset.
    pub source_time_s: f64,
    /// Whether the packet's own source time was kept.
    pub trusted: bool,
    /// What changed with this packet, if anything.
    pub event: Option<ClockEvent>,
}

/// One input's source clock, judged against the receive clock.
#[derive(Clone, Debug)]
pub struct SourceClock {
    params: SourceClockParams,
    /// The previous packet with a finite source time: its source time and offset.
    prev: Option<(f64, f64)>,
    /// Consecutive agreeing packets, this one included.
    run: u32,
    trusted: bool,
    /// The trusted epoch has lasted `steady_packets` packets (a jump before that, at the
    /// start, means the first offset was the bad one: trust starts over).
    established: bool,
    /// The offset of the newest trusted packet (`None` before any).
    offset_s: Option<f64>,
    /// Packets stamped from the receive clock in the current episode.
    untrusted_packets: u64,
}

impl SourceClock {
    pub fn new(params: SourceClockParams) -> Self {
        Self {
            params,
            prev: None,
            run: 0,
            trusted: true,
            established: false,
            offset_s: None,
            untrusted_packets: 0,
        }
    }

    /// Whether the newest packet's own source time was trusted.
    pub fn is_trusted(&self) -> bool {
        self.trusted
    }

    /// Judges one packet received at `receive_s` (stage clock) carrying `source_s`.
    pub fn stamp(&mut self, receive_s: f64, source_s: f64) -> Stamp {
        let offset = source_s - receive_s;
        let finite = offset.is_finite();
        let p = self.params;
        let (agrees, change) = match self.prev {
            None => (finite, 0.0),
            Some((prev_source, prev_offset)) => (
                finite
                    && (offset - prev_offset).abs() <= p.max_jump_s
                    && source_s >= prev_source - p.backwards_tolerance_s,
                offset - prev_offset,
            ),
        };
        if finite {
            self.prev = Some((source_s, offset));
        }
        self.run = if agrees {
            self.run.saturating_add(1)
        } else {
            u32::from(finite)
        };
        let steady = self.run >= p.steady_packets;
        let jumped = ClockEvent::Jumped {
            source_time_s: source_s,
            offset_change_s: if finite { change } else { f64::NAN },
        };
        // Whether this packet's own time is taken: once established, while it agrees (or,
        // after a jump, once enough agree in a row); before, any finite time (a jump while
        // settling means the earlier offset was the bad one).
        let take = match (self.established, self.trusted) {
            (true, true) => agrees,
            (true, false) => steady,
            (false, _) => finite,
        };
        if take {
            let event = if !self.trusted {
                Some(ClockEvent::Steady {
                    untrusted_packets: std::mem::take(&mut self.untrusted_packets),
                })
            } else {
                (!agrees).then_some(jumped)
            };
            self.trusted = true;
            self.established |= steady;
            self.offset_s = Some(offset);
            return Stamp {
                source_time_s: source_s,
                trusted: true,
                event,
            };
        }
        let event = self.trusted.then_some(jumped);
        self.trusted = false;
        self.untrusted_packets += 1;
        Stamp {
            // The receive time plus the last trusted offset (the receive time itself
            // before any).
            source_time_s: receive_s + self.offset_s.unwrap_or(0.0),
            trusted: false,
            event,
        }
    }
}
#[cfg(test)]
mod tests {
    use super::*;

    fn clock() -> SourceClock {
        SourceClock::new(SourceClockParams {
            max_jump_s: 1.0,
            backwards_tolerance_s: 0.05,
            steady_packets: 3,
        })
    }

    /// `(receive, source)` pairs through a clock: each packet's stamped time and trust.
    fn run(c: &mut SourceClock, packets: &[(f64, f64)]) -> Vec<(f64, bool)> {
        packets
            .iter()
            .map(|&(r, s)| {
                let st = c.stamp(r, s);
                (st.source_time_s, st.trusted)
            })
            .collect()
    }

    #[test]
    fn a_steady_clock_passes_through_with_its_jitter_and_drift() {
        let mut c = clock();
        // Source 1000 s ahead, with a few hundred milliseconds of receive jitter.
        let got = run(
            &mut c,
            &[(0.0, 1000.0), (0.1, 1000.45), (0.5, 1000.5), (0.6, 1000.9)],
        );
        assert_eq!(
            got,
            [
                (1000.0, true),
                (1000.45, true),
                (1000.5, true),
                (1000.9, true)
            ]
        );
    }

    #[test]
    fn one_far_future_time_is_replaced_and_trust_comes_back_after_steady_packets() {
        let mut c = clock();
        let mut packets: Vec<(f64, f64)> = (0..5).map(|i| (i as f64, 100.0 + i as f64)).collect();
        // Packet 5: an OSC time tag of 0xFFFFFFFF s (Unix 2085978495 s).
        packets.push((5.0, 2_085_978_495.0));
        packets.extend((6..10).map(|i| (i as f64, 100.0 + i as f64)));
        let stamps: Vec<Stamp> = packets.iter().map(|&(r, s)| c.stamp(r, s)).collect();
        // The bad packet is stamped 5 + 100 (the last trusted offset), and so are the two
        // packets after it: the first disagrees with the bad one, the second makes a run of
        // two; the third (a run of three) is trusted again.
        let got: Vec<(f64, bool)> = stamps
            .iter()
            .map(|s| (s.source_time_s, s.trusted))
            .collect();
        let want: Vec<(f64, bool)> = (0..10)
            .map(|i| (100.0 + i as f64, !(5..8).contains(&i)))
            .collect();
        assert_eq!(got, want);
        assert_eq!(
            stamps[5].event,
            Some(ClockEvent::Jumped {
                source_time_s: 2_085_978_495.0,
                offset_change_s: 2_085_978_495.0 - 5.0 - 100.0,
            })
        );
        assert_eq!(
            stamps[8].event,
            Some(ClockEvent::Steady {
                untrusted_packets: 3
            })
        );
        assert!(stamps
            .iter()
            .enumerate()
            .all(|(i, s)| s.event.is_none() || i == 5 || i == 8));
    }

    #[test]
    fn a_restarted_source_is_trusted_at_its_new_offset_once_steady() {
        let mut c = clock();
        // A server restarts at receive time 10: its clock goes from 50 back to 0.
        let mut packets: Vec<(f64, f64)> = (0..5).map(|i| (i as f64, 46.0 + i as f64)).collect();
        packets.extend((10..15).map(|i| (i as f64, (i - 10) as f64)));
        let got = run(&mut c, &packets);
        assert_eq!(
            &got[..5],
            &[
                (46.0, true),
                (47.0, true),
                (48.0, true),
                (49.0, true),
                (50.0, true)
            ]
        );
        // Packets 10, 11: receive + 46; 12 (three at the new offset of -10): trusted.
        assert_eq!(
            &got[5..],
            &[
                (56.0, false),
                (57.0, false),
                (2.0, true),
                (3.0, true),
                (4.0, true)
            ]
        );
    }

    #[test]
    fn small_reordering_passes_and_a_step_back_does_not() {
        let mut c = clock();
        let got = run(
            &mut c,
            &[
                (0.0, 10.0),
                (0.25, 10.25),
                (0.5, 10.218_75),
                (0.75, 10.75),
                (1.0, 10.0),
            ],
        );
        // 10.25 → 10.21875 is back 31 ms (within 50 ms); 10.75 → 10.0 is back 0.75 s with
        // an offset change of exactly 1 s (allowed): a jump by the backwards rule, stamped
        // 1.0 + 10.0 (the last trusted offset, packet 3's).
        assert_eq!(
            got,
            [
                (10.0, true),
                (10.25, true),
                (10.218_75, true),
                (10.75, true),
                (11.0, false)
            ]
        );
    }

    #[test]
    fn a_bad_first_packet_costs_only_itself() {
        let mut c = clock();
        // The first packet's time is the bad one: nothing is established yet, so the next
        // packet's offset is taken at once (and counted as a jump).
        let first = c.stamp(0.0, 2_085_978_495.0);
        assert_eq!(
            (first.source_time_s, first.trusted),
            (2_085_978_495.0, true)
        );
        let second = c.stamp(0.01, 100.01);
        assert_eq!((second.source_time_s, second.trusted), (100.01, true));
        assert!(matches!(second.event, Some(ClockEvent::Jumped { .. })));
        let got = run(&mut c, &[(0.02, 100.02), (0.03, 100.03)]);
        assert_eq!(got, [(100.02, true), (100.03, true)]);
    }

    #[test]
    fn non_finite_source_times_are_replaced() {
        let mut c = clock();
        let got = run(
            &mut c,
            &[
                (0.0, f64::NAN),
                (1.0, 11.0),
                (2.0, 12.0),
                (3.0, 13.0),
                (4.0, f64::INFINITY),
                (5.0, 15.0),
            ],
        );
        // Before any offset: the receive time itself, and the first finite time is taken
        // at once. Packet 4: receive + 10; packet 5 agrees with packet 3 (the last finite
        // one) but the infinity broke the run: it waits for three in a row.
        assert_eq!(
            got,
            [
                (0.0, false),
                (11.0, true),
                (12.0, true),
                (13.0, true),
                (14.0, false),
                (15.0, false)
            ]
        );
    }
}
