#![no_main]
//! Arbitrary byte streams into the VRPN message decoder and its description and
//! position parsers.
use libfuzzer_sys::fuzz_target;
use rigless::protocol::vrpn::{decode_message, parse_pos_quat, Names};

fuzz_target!(|data: &[u8]| {
    let mut names = Names::default();
    let mut at = 0;
    while let Ok(Some((m, n))) = decode_message(&data[at..]) {
        let _ = names.observe(&m);
        let _ = parse_pos_quat(m.payload);
        at += n;
    }
});
