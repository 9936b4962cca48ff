//! A counting global allocator for the tests that bound what reading a file may allocate.
//! Per thread (the readers run on the calling thread, and the test harness runs tests on
//! several): the live bytes, their peak and the largest single request, so a test can
//! measure one call. It refuses any request that would take a thread past [`CEILING`], so
//! a reader that asks for gigabytes fails its test (the process aborts with "memory
//! allocation of N bytes failed") instead of exhausting the machine.

#![allow(dead_code)] // each test binary uses its own subset

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

/// Most bytes one thread may hold at once: 1 GiB, far above what any test here needs.
pub const CEILING: usize = 1 << 30;

/// What a reader may hold at its peak while reading a file of `len` bytes: 64 MiB and
/// 64 bytes per byte. The readers allocate at most `position_budget(len)` = 2^20 + `len`
/// positions (24 bytes each, and a 24-byte frame header each when a frame holds one
/// marker: 48 MiB and 48 bytes per byte), and the rest (session samples, 56 bytes per
/// 33-byte sample; TSV rows, 24 bytes per 3 bytes; names; vectors growing) fits in the
/// remaining 16 MiB and 16 bytes per byte.
pub fn peak_bound(len: usize) -> usize {
    (64 << 20) + 64 * len
}

/// The largest single request a reader may make for a file of `len` bytes: 32 MiB and 32
/// bytes per byte (the frame table's outer vector, 24 bytes a frame, is the largest).
pub fn largest_bound(len: usize) -> usize {
    (32 << 20) + 32 * len
}

/// What one measured call allocated.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Usage {
    /// Highest live bytes during the call, above those live when it started.
    pub peak: usize,
    /// Largest single request (allocation or reallocation's new size).
    pub largest: usize,
}

impl Usage {
    /// Panics (this is a test) unless both figures are within the bounds for `len` bytes.
    pub fn assert_within(self, len: usize, what: &str) {
        assert!(
            self.peak <= peak_bound(len) && self.largest <= largest_bound(len),
            "{what}: {len} bytes read with a peak of {} bytes (bound {}) and a largest \
             request of {} bytes (bound {})",
            self.peak,
            peak_bound(len),
            self.largest,
            largest_bound(len)
        );
    }
}

thread_local! {
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

/// The counting allocator (over the system allocator).
pub struct Meter;

#[global_allocator]
static METER: Meter = Meter;

/// Accounts for `grow` more bytes (negative: fewer); `false` when a request of
/// `request` bytes would take the thread past [`CEILING`].
fn account(grow: isize, request: usize) -> bool {
    // `try_with`: the cells have no destructor, but a thread's last frees may still
    // come after its locals are gone.
    LIVE.try_with(|live| {
        let now = live.get().saturating_add(grow);
        if grow > 0 && now > CEILING as isize {
            return false;
        }
        live.set(now);
        PEAK.with(|p| p.set(p.get().max(now)));
        LARGEST.with(|l| l.set(l.get().max(request)));
        true
    })
    .unwrap_or(true)
}

unsafe impl GlobalAlloc for Meter {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !account(layout.size() as isize, layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller's layout, passed on unchanged.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if !account(layout.size() as isize, layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller's layout, passed on unchanged.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        account(-(layout.size() as isize), 0);
        // SAFETY: `ptr` came from `System` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let grow = new_size as isize - layout.size() as isize;
        if !account(grow, new_size) {
            return std::ptr::null_mut();
        }
        // SAFETY: `ptr` came from `System` with this layout; the caller checked `new_size`.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if p.is_null() {
            account(-grow, 0);
        }
        p
    }
}

/// Runs `f` and returns its result with what it allocated on this thread.
pub fn measure<T>(f: impl FnOnce() -> T) -> (T, Usage) {
    let base = LIVE.with(Cell::get);
    PEAK.with(|p| p.set(base));
    LARGEST.with(|l| l.set(0));
    let out = f();
    let usage = Usage {
        peak: (PEAK.with(Cell::get) - base).max(0) as usize,
        largest: LARGEST.with(Cell::get),
    };
    (out, usage)
}

#[test]
fn the_meter_counts_peak_and_largest() {
    let ((), u) = measure(|| {
        let a = vec![0u8; 1000];
        let b = vec![0u8; 3000];
        drop(a);
        let mut c: Vec<u8> = Vec::with_capacity(10);
        c.extend_from_slice(&[1; 20]);
        drop((b, c));
    });
    // 1000 + 3000 live at once; `c` reallocated from 10 to 20 (or more) with `a` gone.
    assert_eq!(u.largest, 3000);
    assert_eq!(u.peak, 4000);
}
