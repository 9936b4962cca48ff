#![no_main]
//! Arbitrary text into the BVH reader.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = rigless::replay::bvh::parse_bvh(&String::from_utf8_lossy(data), 0.01);
});
