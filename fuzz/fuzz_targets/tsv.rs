#![no_main]
//! Arbitrary text into the Qualisys TSV reader.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = rigless::replay::tsv::parse_tsv(&String::from_utf8_lossy(data));
});
