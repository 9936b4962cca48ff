#![no_main]
//! Arbitrary files into the session reader and its grouping into frames.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // Only a panic or an allocation past libFuzzer's -rss_limit_mb is a finding.
    let _ = rigless::replay::recording::Recording::from_session_bytes("fuzz", data);
});
