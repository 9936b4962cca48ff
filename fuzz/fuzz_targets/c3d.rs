#![no_main]
//! Arbitrary files into the C3D reader.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = rigless::replay::c3d::read_c3d(data);
});
