//! Helpers shared by the integration tests.

use std::path::PathBuf;

/// A file of `../shared/data` (real recordings, meshes, captures), or `None` with the
/// reason printed when it is absent (the tests that need it then skip).
pub fn shared_file(rel: &str) -> Option<Vec<u8>> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(rel);
    match std::fs::read(&p) {
        Ok(b) => Some(b),
        Err(e) => {
            println!("skipping: {}: {e}", p.display());
            None
        }
    }
}
