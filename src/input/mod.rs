//! Input sources that feed marker samples into the daemon's bounded channel.

pub mod osc;
pub mod synthetic;

use crate::markers::MarkerSample;
use crossbeam_channel::{Sender, TrySendError};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// What a running source has done (shared with the status line).
#[derive(Debug, Default)]
pub struct SourceCounters {
    /// Frames sent.
    pub frames: AtomicU64,
    /// Samples sent.
    pub samples: AtomicU64,
    /// Samples dropped because the channel was full.
    pub dropped: AtomicU64,
    /// Set when the session has ended (not looping).
    pub finished: AtomicBool,
}

/// Sends one frame's samples without blocking: a full channel drops (and counts) the
/// sample. Returns false once the receiver is gone.
pub fn send_samples(batch: &[MarkerSample], tx: &Sender<MarkerSample>, c: &SourceCounters) -> bool {
    for s in batch {
        match tx.try_send(*s) {
            Ok(()) => {
                c.samples.fetch_add(1, Ordering::Relaxed);
            }
            Err(TrySendError::Full(_)) => {
                c.dropped.fetch_add(1, Ordering::Relaxed);
            }
            Err(TrySendError::Disconnected(_)) => return false,
        }
    }
    true
}
