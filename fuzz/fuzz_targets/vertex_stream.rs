#![no_main]
//! Arbitrary bytes into the vertex stream decoder (what a client reads).
use libfuzzer_sys::fuzz_target;
use rigless::protocol::vertex_stream::decode;

fuzz_target!(|data: &[u8]| {
    let _ = decode(data);
});
