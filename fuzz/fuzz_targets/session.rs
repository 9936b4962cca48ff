#![no_main]
//! Arbitrary files into the session reader.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = rigless::replay::session::read_session(data);
});
