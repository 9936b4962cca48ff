#![no_main]
//! Arbitrary datagrams into the NatNet decoder, for each protocol version it reads.
use libfuzzer_sys::fuzz_target;
use rigless::protocol::natnet::{decode, Version};

fuzz_target!(|data: &[u8]| {
    for v in [Version(3, 0), Version(4, 0), Version(4, 1)] {
        let _ = decode(data, v);
    }
});
