//! The latest-value slot between the solver thread and one sink: the loop publishes an
//! `Arc` frame without blocking or locking; the sink takes the newest one when it is
//! ready. A frame replaced before the sink took it is dropped and counted.
//!
//! Both sides only `swap` one atomic pointer, so each `Arc` is owned by exactly one side
//! at a time: the slot owns what is in it, the taker owns what it took, and the publisher
//! owns (and drops) what it replaced.

use std::ptr;
use std::sync::atomic::{AtomicPtr, AtomicU64, Ordering};
use std::sync::Arc;
use tokio::sync::Notify;

/// A single-value mailbox holding the newest `Arc<T>`.
pub struct LatestSlot<T> {
    ptr: AtomicPtr<T>,
    /// Frames replaced before being taken.
    dropped: AtomicU64,
    /// Frames published.
    published: AtomicU64,
    notify: Notify,
}

impl<T> Default for LatestSlot<T> {
    fn default() -> Self {
        Self {
            ptr: AtomicPtr::new(ptr::null_mut()),
            dropped: AtomicU64::new(0),
            published: AtomicU64::new(0),
            notify: Notify::new(),
        }
    }
}

impl<T> LatestSlot<T> {
    pub fn new() -> Self {
        Self::default()
    }

    /// Puts `v` in the slot; drops (and counts) an untaken older value.
    pub fn publish(&self, v: Arc<T>) {
        let old = self.ptr.swap(Arc::into_raw(v) as *mut T, Ordering::AcqRel);
        self.published.fetch_add(1, Ordering::Relaxed);
        if !old.is_null() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            // SAFETY: `old` came from `Arc::into_raw` in `publish`, and the swap made this
            // call its only owner.
            drop(unsafe { Arc::from_raw(old) });
        }
        self.notify.notify_one();
    }

    /// Takes the newest value, if one arrived since the last take.
    pub fn take(&self) -> Option<Arc<T>> {
        let p = self.ptr.swap(ptr::null_mut(), Ordering::AcqRel);
        // SAFETY: as in `publish`: the swap transferred ownership of `p` to this call.
        (!p.is_null()).then(|| unsafe { Arc::from_raw(p) })
    }

    /// Waits (async) until a value is there, then takes it.
    pub async fn next(&self) -> Arc<T> {
        loop {
            if let Some(v) = self.take() {
                return v;
            }
            self.notify.notified().await;
        }
    }

    /// Wakes a waiting `next` without a value (used at shutdown).
    pub fn wake(&self) {
        self.notify.notify_one();
    }

    /// Frames replaced before the sink took them.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    pub fn published(&self) -> u64 {
        self.published.load(Ordering::Relaxed)
    }
}

impl<T> Drop for LatestSlot<T> {
    fn drop(&mut self) {
        drop(self.take());
    }
}

// SAFETY: the slot hands `Arc<T>` between threads; that is sound when `Arc<T>` is Send,
// i.e. `T: Send + Sync`.
unsafe impl<T: Send + Sync> Send for LatestSlot<T> {}
unsafe impl<T: Send + Sync> Sync for LatestSlot<T> {}

/// The newest joint angles a source imposes on the posture (a data glove), for the
/// solver thread: the source replaces them under a short lock; the loop copies them only
/// when they changed (no allocation on either side).
pub struct PinSlot {
    version: AtomicU64,
    pins: std::sync::Mutex<Vec<f64>>,
}

impl PinSlot {
    /// A slot for `n` posture parameters, all free (NaN).
    pub fn new(n: usize) -> Self {
        Self {
            version: AtomicU64::new(0),
            pins: std::sync::Mutex::new(vec![f64::NAN; n]),
        }
    }

    /// Changes the angles in place (`write` sees the current ones).
    pub fn write(&self, write: impl FnOnce(&mut [f64])) {
        let mut pins = self.pins.lock().unwrap_or_else(|p| p.into_inner());
        write(&mut pins);
        self.version.fetch_add(1, Ordering::Release);
    }

    /// Copies the angles into `out` if they changed since version `seen` (updated);
    /// returns whether they did.
    pub fn read_if_newer(&self, seen: &mut u64, out: &mut [f64]) -> bool {
        let v = self.version.load(Ordering::Acquire);
        if v == *seen {
            return false;
        }
        let pins = self.pins.lock().unwrap_or_else(|p| p.into_inner());
        let n = out.len().min(pins.len());
        out[..n].copy_from_slice(&pins[..n]);
        *seen = v;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newest_wins_and_replaced_values_are_counted_and_freed() {
        let slot = LatestSlot::new();
        let a = Arc::new(1);
        slot.publish(Arc::clone(&a));
        slot.publish(Arc::new(2));
        assert_eq!(Arc::strong_count(&a), 1, "replaced value freed");
        assert_eq!(*slot.take().unwrap(), 2);
        assert!(slot.take().is_none());
        assert_eq!((slot.published(), slot.dropped()), (2, 1));
    }

    #[test]
    fn values_cross_threads_without_loss_of_the_newest() {
        let slot = Arc::new(LatestSlot::new());
        let s2 = Arc::clone(&slot);
        let writer = std::thread::spawn(move || {
            for i in 0..10_000u64 {
                s2.publish(Arc::new(i));
            }
        });
        let mut last = 0;
        let mut taken = 0u64;
        // Bounded: a lost newest value fails the test instead of hanging it (10,000
        // publishes take milliseconds; 20 s is a stalled machine).
        let start = std::time::Instant::now();
        while last != 9_999 {
            assert!(
                start.elapsed() < std::time::Duration::from_secs(20),
                "the newest value never arrived (last taken {last})"
            );
            if let Some(v) = slot.take() {
                assert!(*v >= last, "values arrive in order");
                last = *v;
                taken += 1;
            }
        }
        writer.join().unwrap();
        assert_eq!(taken + slot.dropped(), 10_000);
    }
}
