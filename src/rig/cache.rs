//! The bake cache: the expensive part of a bound [`Rig`], its Green coordinates, stored
//! next to its character file and keyed by a hash of the inputs, so the next start skips
//! computing them. Loading rebuilds everything else (lattice, factorization, posture
//! model: milliseconds) and takes the stored coordinates only if they were made for the
//! very control mesh it rebuilt ([`Rig::lattice_key`]) and fit it: the file supplies no
//! index, count or structure the solver trusts.
//!
//! File layout (little-endian):
//!
//! ```text
//! 0   12  magic "RIGLESS-RIG\0"
//! 12   4  u32 format version (FORMAT_VERSION)
//! 16   8  u64 inputs hash (mesh file and its parse, crate version)
//! 24   8  u64 payload length in bytes
//! 32   8  u64 FNV-1a of the payload
//! 40   …  payload: the Green coordinates with their lattice key (`StoredGreen`),
//!          bincode (default options)
//! ```
//!
//! The file is untrusted input: a wrong magic, version, key, length or checksum makes it
//! stale (the caller rebuilds), and decoding is limited to the payload's length, so a
//! corrupt length field cannot make it allocate.

use super::bind::{BindError, BindStage, Rig, StoredGreen, StoredGreenMiss};
use crate::character::file::{fnv1a, LoadedCharacter};
use crate::runtime::files::{read_bounded, MAX_DATA_BYTES};
use bincode::Options;
use std::path::{Path, PathBuf};

/// Magic bytes at the start of a cache file.
pub const MAGIC: &[u8; 12] = b"RIGLESS-RIG\0";
/// Bumped whenever the stored rig's layout changes.
pub const FORMAT_VERSION: u32 = 6;
const HEADER_LEN: usize = 40;

/// Why a cache file was not used (the caller rebinds and says why).
#[derive(Debug, thiserror::Error)]
pub enum CacheMiss {
    #[error("no cache file yet")]
    Absent,
    #[error("cannot read the cache file: {0}")]
    Io(std::io::Error),
    #[error("not a rigless cache file")]
    BadMagic,
    #[error("cache format {found} (this build reads {FORMAT_VERSION})")]
    Version { found: u32 },
    #[error("the mesh changed since the bake")]
    Stale,
    #[error("the cache file is truncated or corrupt")]
    Corrupt,
    #[error("the cache file could not be decoded: {0}")]
    Decode(String),
    #[error("the cached Green coordinates do not fit the rebuilt control mesh: {0}")]
    Unfit(StoredGreenMiss),
}

/// Errors writing a cache file.
#[derive(Debug, thiserror::Error)]
pub enum CacheWriteError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("encoding the rig: {0}")]
    Encode(String),
}

/// The cache file of a character file: same folder and stem, extension `rigcache`.
pub fn cache_path(character: &Path) -> PathBuf {
    character.with_extension("rigcache")
}

fn options() -> impl Options {
    bincode::DefaultOptions::new()
}

/// Encodes a rig's stored part with its inputs hash (pure: bytes out).
pub fn encode(rig: &Rig, inputs_hash: u64) -> Result<Vec<u8>, CacheWriteError> {
    encode_stored(&rig.stored_green(), inputs_hash)
}

/// Encodes stored Green coordinates with an inputs hash (pure: bytes out).
pub fn encode_stored(stored: &StoredGreen, inputs_hash: u64) -> Result<Vec<u8>, CacheWriteError> {
    let payload = options()
        .serialize(stored)
        .map_err(|e| CacheWriteError::Encode(e.to_string()))?;
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&inputs_hash.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&fnv1a(&[&payload]).to_le_bytes());
    out.extend_from_slice(&payload);
    Ok(out)
}

/// Decodes a cache file's bytes, checking them against the expected inputs hash (pure).
pub fn decode(bytes: &[u8], inputs_hash: u64) -> Result<StoredGreen, CacheMiss> {
    if bytes.len() < HEADER_LEN || &bytes[..12] != MAGIC {
        return Err(CacheMiss::BadMagic);
    }
    let u64_at = |o: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&bytes[o..o + 8]);
        u64::from_le_bytes(b)
    };
    let mut v = [0u8; 4];
    v.copy_from_slice(&bytes[12..16]);
    let version = u32::from_le_bytes(v);
    if version != FORMAT_VERSION {
        return Err(CacheMiss::Version { found: version });
    }
    if u64_at(16) != inputs_hash {
        return Err(CacheMiss::Stale);
    }
    let len = u64_at(24);
    let payload = &bytes[HEADER_LEN..];
    if payload.len() as u64 != len || fnv1a(&[payload]) != u64_at(32) {
        return Err(CacheMiss::Corrupt);
    }
    options()
        .with_limit(len)
        .deserialize(payload)
        .map_err(|e| CacheMiss::Decode(e.to_string()))
}

/// Loads the stored part of a character file's rig if it is there and current.
pub fn load(character: &Path, inputs_hash: u64) -> Result<StoredGreen, CacheMiss> {
    let path = cache_path(character);
    let bytes = match read_bounded(&path, MAX_DATA_BYTES) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Err(CacheMiss::Absent),
        Err(e) => return Err(CacheMiss::Io(e)),
    };
    decode(&bytes, inputs_hash)
}

/// Writes the cache file of a character file (to a temporary name, then renamed, so a
/// crash never leaves a half-written cache behind).
pub fn store(character: &Path, rig: &Rig, inputs_hash: u64) -> Result<PathBuf, CacheWriteError> {
    let path = cache_path(character);
    let tmp = path.with_extension("rigcache.tmp");
    let bytes = encode(rig, inputs_hash)?;
    let io = |source| CacheWriteError::Io {
        path: path.display().to_string(),
        source,
    };
    std::fs::write(&tmp, &bytes).map_err(io)?;
    std::fs::rename(&tmp, &path).map_err(io)?;
    Ok(path)
}

/// Where a loaded or bound rig came from.
#[derive(Debug)]
pub enum RigSource {
    /// Read from the cache file in this many seconds.
    Cache { path: PathBuf, seconds: f64 },
    /// Bound (the cache was forced aside, or missed for this reason) and written here.
    Bound {
        miss: Option<CacheMiss>,
        written: PathBuf,
    },
}

impl std::fmt::Display for RigSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RigSource::Cache { path, seconds } => {
                write!(f, "loaded {} in {seconds:.3} s", path.display())
            }
            RigSource::Bound { miss, written } => {
                let why = miss
                    .as_ref()
                    .map_or("--force".to_owned(), ToString::to_string);
                write!(f, "bound ({why}); wrote {}", written.display())
            }
        }
    }
}

/// Why a character file's rig could not be had.
#[derive(Debug, thiserror::Error)]
pub enum LoadOrBindError {
    #[error("binding {path}: {source}")]
    Bind { path: String, source: BindError },
    #[error(transparent)]
    Write(#[from] CacheWriteError),
}

/// The bound rig of a loaded character file (`path` is the character file): from its
/// bake cache when current (and not `force`), else bound (`progress` hears each stage's
/// fraction done) and cached.
pub fn load_or_bind(
    path: &Path,
    loaded: &LoadedCharacter,
    force: bool,
    progress: &mut dyn FnMut(BindStage, f64),
) -> Result<(Rig, RigSource), LoadOrBindError> {
    let t0 = std::time::Instant::now();
    let (stored, mut miss) = match (force, load(path, loaded.inputs_hash)) {
        (true, _) => (None, None),
        (false, Ok(stored)) => (Some(stored), None),
        (false, Err(miss)) => (None, Some(miss)),
    };
    let reusing = stored.is_some();
    let (rig, unused) = Rig::bind_reusing(&loaded.character, &loaded.bind, progress, stored)
        .map_err(|source| LoadOrBindError::Bind {
            path: path.display().to_string(),
            source,
        })?;
    match unused {
        None if reusing => {
            let source = RigSource::Cache {
                path: cache_path(path),
                seconds: t0.elapsed().as_secs_f64(),
            };
            return Ok((rig, source));
        }
        None => {}
        Some(unfit) => miss = Some(CacheMiss::Unfit(unfit)),
    }
    let written = store(path, &rig, loaded.inputs_hash)?;
    Ok((rig, RigSource::Bound { miss, written }))
}
