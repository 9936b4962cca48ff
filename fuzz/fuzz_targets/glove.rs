#![no_main]
//! Arbitrary byte streams through the glove line framer into both line decoders.
use libfuzzer_sys::fuzz_target;
use rigless::protocol::glove::{decode_line, GloveFormat, GloveReading, LineFramer};

fuzz_target!(|data: &[u8]| {
    let mut framer = LineFramer::default();
    let mut r = GloveReading::default();
    framer.push(data, &mut |line| {
        if let Ok(line) = line {
            let _ = decode_line(line, GloveFormat::Alpha, 4095, &mut r);
            let _ = decode_line(line, GloveFormat::Legacy, 4095, &mut r);
        }
    });
});
