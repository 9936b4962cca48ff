#![no_main]
//! Arbitrary datagrams into the OSC decoder (native schema, patterns, VMC).
use libfuzzer_sys::fuzz_target;
use rigless::protocol::osc::{OscFrame, OscMapping};

fuzz_target!(|data: &[u8]| {
    let mut f = OscFrame::default();
    let _ = OscMapping::default().decode_into(data, &mut f);
});
