//! Test support: what `tracing` logs while a closure runs, as text (for tests that check
//! a warning is logged once, not per sample).

use std::io::Write;
use std::sync::{Arc, Mutex};

/// A writer appending to a shared buffer.
#[derive(Clone, Default)]
struct Shared(Arc<Mutex<Vec<u8>>>);

impl Write for Shared {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Runs `f` with every event of this thread at `INFO` and above logged, one line each,
/// without colours; returns `f`'s result and the lines.
pub fn captured<T>(f: impl FnOnce() -> T) -> (T, String) {
    let out = Shared::default();
    let writer = out.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_writer(move || writer.clone())
        .with_ansi(false)
        .with_max_level(tracing::Level::INFO)
        .finish();
    let r = tracing::subscriber::with_default(subscriber, f);
    let bytes = out.0.lock().unwrap_or_else(|e| e.into_inner()).clone();
    (r, String::from_utf8_lossy(&bytes).into_owned())
}
