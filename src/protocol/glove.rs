//! Serial data-glove lines as OpenGloves / LucidGloves firmware sends them (one reading
//! per `\n`-terminated ASCII line): the "alpha" encoding (`A1024B2048...(AB)2047...`) and
//! the legacy `&`-separated one; plus a line framer over a byte stream. Pure: bytes in,
//! readings out, no I/O, no allocation. The wire format is in `protocols/glove.md`.

/// Fingers in wire order.
pub const FINGERS: [&str; 5] = ["thumb", "index", "middle", "ring", "pinky"];

/// The firmware's default full-scale reading (12-bit ADC).
pub const DEFAULT_MAX_VALUE: u32 = 4095;

/// Longest line accepted, bytes (the firmware's own buffer is 100–256 bytes; a full alpha
/// line with every per-joint key is about 200).
pub const MAX_LINE_BYTES: usize = 512;

/// Longest number accepted, digits (more would overflow nothing a glove sends).
const MAX_DIGITS: usize = 9;

/// Which encoding a glove sends.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GloveFormat {
    /// Keys and values, e.g. `A0B2048C4095D0E0(AB)2047F2047G2047\n`.
    Alpha,
    /// `thumb&index&middle&ring&pinky&joyX&joyY&joyBtn&trigger&A&B&grab&pinch\n`.
    Legacy,
}

/// Buttons and gestures (bit flags; pressed when set).
pub mod buttons {
    pub const JOYSTICK: u16 = 1 << 0;
    pub const TRIGGER: u16 = 1 << 1;
    pub const A: u16 = 1 << 2;
    pub const B: u16 = 1 << 3;
    pub const GRAB: u16 = 1 << 4;
    pub const PINCH: u16 = 1 << 5;
    pub const MENU: u16 = 1 << 6;
    pub const CALIBRATE: u16 = 1 << 7;
    /// Names in bit order.
    pub const NAMES: [&str; 8] = [
        "joystick",
        "trigger",
        "a",
        "b",
        "grab",
        "pinch",
        "menu",
        "calibrate",
    ];
}

/// One decoded line. Analog values are raw readings (0..=max); a field the line did not
/// carry is `None`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GloveReading {
    /// Whole-finger curl per finger (thumb..pinky): 0 open, max closed.
    pub curl: [Option<u32>; 5],
    /// Per-joint curl, joints 0 (base) to 3 (alpha keys `(AAA)`..`(EAD)`).
    pub joint_curl: [[Option<u32>; 4]; 5],
    /// Splay per finger (alpha keys `(AB)`..`(EB)`): max/2 straight.
    pub splay: [Option<u32>; 5],
    /// Joystick x and y: max/2 centred.
    pub joystick: [Option<u32>; 2],
    /// Analog trigger.
    pub trigger: Option<u32>,
    /// Pressed buttons and active gestures, [`buttons`] flags.
    pub buttons: u16,
    /// Alpha keys this decoder does not know (skipped, for firmware newer than it).
    pub unknown_keys: u8,
}

impl GloveReading {
    /// Raw curl of joint `k` (0..3) of finger `f`: the joint's own reading when sent,
    /// otherwise the whole finger's.
    pub fn joint_raw(&self, f: usize, k: usize) -> Option<u32> {
        self.joint_curl[f][k].or(self.curl[f])
    }
}

/// Why a line was rejected (offsets count bytes from the line's start).
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum GloveError {
    #[error("empty line")]
    Empty,
    #[error("byte {byte:#04x} at offset {offset} is not a key, digit or separator")]
    BadByte { offset: usize, byte: u8 },
    #[error("number at offset {offset} has no key before it")]
    ValueWithoutKey { offset: usize },
    #[error("key at offset {offset} is not closed with ')'")]
    UnclosedKey { offset: usize },
    #[error("number at offset {offset} has more than {MAX_DIGITS} digits")]
    TooLong { offset: usize },
    #[error("value {value} at offset {offset} is above the full scale {max}")]
    AboveMax { offset: usize, value: u32, max: u32 },
    #[error("legacy line has {fields} fields (expected 5 to 13)")]
    FieldCount { fields: usize },
    #[error("legacy field {index} ({text:?}) is not a number")]
    BadField { index: usize, text: String },
    #[error("line carries no known key")]
    NoData,
    #[error("line longer than {MAX_LINE_BYTES} bytes")]
    Overlong,
}

/// Decodes one line (without its `\n`; a trailing `\r` and spaces are ignored) into
/// `out`, which is reset first. `max` is the full-scale reading.
pub fn decode_line(
    line: &[u8],
    format: GloveFormat,
    max: u32,
    out: &mut GloveReading,
) -> Result<(), GloveError> {
    *out = GloveReading::default();
    let end = line
        .iter()
        .rposition(|b| !b.is_ascii_whitespace())
        .map_or(0, |i| i + 1);
    let line = &line[..end];
    if line.is_empty() {
        return Err(GloveError::Empty);
    }
    if line.len() > MAX_LINE_BYTES {
        return Err(GloveError::Overlong);
    }
    match format {
        GloveFormat::Alpha => decode_alpha(line, max, out),
        GloveFormat::Legacy => decode_legacy(line, max, out),
    }
}

/// Reads the digits at `at`, if any: `(value, end)`.
fn number(line: &[u8], at: usize) -> Result<Option<(u32, usize)>, GloveError> {
    let n = line[at..].iter().take_while(|b| b.is_ascii_digit()).count();
    if n == 0 {
        return Ok(None);
    }
    if n > MAX_DIGITS {
        return Err(GloveError::TooLong { offset: at });
    }
    let v = line[at..at + n]
        .iter()
        .fold(0u32, |v, d| v * 10 + u32::from(d - b'0'));
    Ok(Some((v, at + n)))
}

/// Where an alpha key's value goes.
enum Slot {
    Curl(usize),
    Splay(usize),
    Joint(usize, usize),
    Joy(usize),
    Trigger,
    Button(u16),
    Unknown,
}

fn alpha_slot(key: &[u8]) -> Slot {
    let finger = |c: u8| (b'A'..=b'E').contains(&c).then(|| usize::from(c - b'A'));
    match key {
        [c] => match c {
            b'A'..=b'E' => Slot::Curl(usize::from(c - b'A')),
            b'F' => Slot::Joy(0),
            b'G' => Slot::Joy(1),
            b'H' => Slot::Button(buttons::JOYSTICK),
            b'I' => Slot::Button(buttons::TRIGGER),
            b'J' => Slot::Button(buttons::A),
            b'K' => Slot::Button(buttons::B),
            b'L' => Slot::Button(buttons::GRAB),
            b'M' => Slot::Button(buttons::PINCH),
            b'N' => Slot::Button(buttons::MENU),
            b'O' => Slot::Button(buttons::CALIBRATE),
            b'P' => Slot::Trigger,
            _ => Slot::Unknown,
        },
        [f, b'B'] => finger(*f).map_or(Slot::Unknown, Slot::Splay),
        [f, b'A', j @ b'A'..=b'D'] => {
            finger(*f).map_or(Slot::Unknown, |f| Slot::Joint(f, usize::from(j - b'A')))
        }
        _ => Slot::Unknown,
    }
}

/// The alpha encoding: a key (`A`..`Z`, or upper-case letters in parentheses) and an
/// optional decimal value; a button key with no value is pressed.
fn decode_alpha(line: &[u8], max: u32, out: &mut GloveReading) -> Result<(), GloveError> {
    let mut at = 0;
    let mut known = 0;
    while at < line.len() {
        let start = at;
        let key: &[u8] = match line[at] {
            b'A'..=b'Z' => {
                at += 1;
                &line[start..at]
            }
            b'(' => {
                let close = line[at..]
                    .iter()
                    .position(|&b| b == b')')
                    .ok_or(GloveError::UnclosedKey { offset: start })?;
                let inner = &line[at + 1..at + close];
                if let Some(i) = inner.iter().position(|b| !b.is_ascii_uppercase()) {
                    return Err(GloveError::BadByte {
                        offset: at + 1 + i,
                        byte: inner[i],
                    });
                }
                at += close + 1;
                inner
            }
            b'0'..=b'9' => return Err(GloveError::ValueWithoutKey { offset: at }),
            b' ' | b'\t' | b'\r' => {
                at += 1;
                continue;
            }
            byte => return Err(GloveError::BadByte { offset: at, byte }),
        };
        let value = match number(line, at)? {
            Some((v, end)) => {
                if v > max {
                    return Err(GloveError::AboveMax {
                        offset: at,
                        value: v,
                        max,
                    });
                }
                at = end;
                Some(v)
            }
            None => None,
        };
        let slot = alpha_slot(key);
        known += usize::from(!matches!(slot, Slot::Unknown));
        match (slot, value) {
            (Slot::Curl(f), Some(v)) => out.curl[f] = Some(v),
            (Slot::Splay(f), Some(v)) => out.splay[f] = Some(v),
            (Slot::Joint(f, j), Some(v)) => out.joint_curl[f][j] = Some(v),
            (Slot::Joy(i), Some(v)) => out.joystick[i] = Some(v),
            (Slot::Trigger, Some(v)) => out.trigger = Some(v),
            (Slot::Button(b), _) => out.buttons |= b,
            // An analog key with no value carries nothing.
            (
                Slot::Curl(_) | Slot::Splay(_) | Slot::Joint(..) | Slot::Joy(_) | Slot::Trigger,
                None,
            ) => {}
            (Slot::Unknown, _) => out.unknown_keys = out.unknown_keys.saturating_add(1),
        }
    }
    if known == 0 {
        return Err(GloveError::NoData);
    }
    Ok(())
}

/// The legacy encoding: 5 to 13 `&`-separated decimal fields in the order thumb, index,
/// middle, ring, pinky, joystick x, joystick y, then joystick, trigger, A, B buttons and
/// grab, pinch gestures (non-zero: pressed).
fn decode_legacy(line: &[u8], max: u32, out: &mut GloveReading) -> Result<(), GloveError> {
    const FLAGS: [u16; 6] = [
        buttons::JOYSTICK,
        buttons::TRIGGER,
        buttons::A,
        buttons::B,
        buttons::GRAB,
        buttons::PINCH,
    ];
    let fields = line.split(|&b| b == b'&').count();
    if !(5..=13).contains(&fields) {
        return Err(GloveError::FieldCount { fields });
    }
    let mut offset = 0;
    for (i, field) in line.split(|&b| b == b'&').enumerate() {
        let trimmed = field.trim_ascii();
        let bad = || GloveError::BadField {
            index: i,
            text: String::from_utf8_lossy(&field[..field.len().min(16)]).into_owned(),
        };
        let v = match number(trimmed, 0) {
            Ok(Some((v, end))) if end == trimmed.len() => v,
            Err(GloveError::TooLong { .. }) => return Err(GloveError::TooLong { offset }),
            _ => return Err(bad()),
        };
        if i < 7 && v > max {
            return Err(GloveError::AboveMax {
                offset,
                value: v,
                max,
            });
        }
        match i {
            0..=4 => out.curl[i] = Some(v),
            5 | 6 => out.joystick[i - 5] = Some(v),
            _ if v != 0 => out.buttons |= FLAGS[i - 7],
            _ => {}
        }
        offset += field.len() + 1;
    }
    Ok(())
}

/// Writes `r` as one alpha line (with its `\n`), keys in the firmware's order. For tests,
/// the glove emulator and the protocol document's examples.
pub fn encode_alpha(r: &GloveReading, out: &mut String) {
    use std::fmt::Write;
    for (f, v) in r.curl.iter().enumerate() {
        if let Some(v) = v {
            write!(out, "{}{v}", char::from(b'A' + f as u8))
                .expect("writing to a String cannot fail");
        }
    }
    for (f, joints) in r.joint_curl.iter().enumerate() {
        for (j, v) in joints.iter().enumerate() {
            if let Some(v) = v {
                write!(
                    out,
                    "({}A{}){v}",
                    char::from(b'A' + f as u8),
                    char::from(b'A' + j as u8)
                )
                .expect("writing to a String cannot fail");
            }
        }
    }
    for (f, v) in r.splay.iter().enumerate() {
        if let Some(v) = v {
            write!(out, "({}B){v}", char::from(b'A' + f as u8))
                .expect("writing to a String cannot fail");
        }
    }
    for (i, v) in r.joystick.iter().enumerate() {
        if let Some(v) = v {
            write!(out, "{}{v}", if i == 0 { 'F' } else { 'G' })
                .expect("writing to a String cannot fail");
        }
    }
    if let Some(v) = r.trigger {
        write!(out, "P{v}").expect("writing to a String cannot fail");
    }
    for (bit, key) in "HIJKLMNO".chars().enumerate() {
        if r.buttons & (1 << bit) != 0 {
            out.push(key);
        }
    }
    out.push('\n');
}

/// Writes `r` as one legacy line (curls and joystick; missing values as 0).
pub fn encode_legacy(r: &GloveReading, out: &mut String) {
    use std::fmt::Write;
    for v in r.curl.iter().chain(&r.joystick) {
        write!(out, "{}&", v.unwrap_or(0)).expect("writing to a String cannot fail");
    }
    for bit in 0..6 {
        write!(out, "{}&", u8::from(r.buttons & (1 << bit) != 0))
            .expect("writing to a String cannot fail");
    }
    out.pop();
    out.push('\n');
}

/// What [`LineFramer::push`] hands over: a complete line (without `\n`) or why not.
pub type FramedLine<'a> = Result<&'a [u8], GloveError>;

/// Cuts a byte stream into lines in a fixed buffer: bytes of an overlong line are dropped
/// up to its end (and the line is reported as [`GloveError::Overlong`]).
pub struct LineFramer {
    buf: Box<[u8; MAX_LINE_BYTES]>,
    len: usize,
    overlong: bool,
}

impl Default for LineFramer {
    fn default() -> Self {
        Self {
            buf: Box::new([0; MAX_LINE_BYTES]),
            len: 0,
            overlong: false,
        }
    }
}

impl LineFramer {
    /// Feeds bytes; calls `on_line` with each complete line (without `\n`), or with
    /// `Err(Overlong)` for a line that did not fit.
    pub fn push(&mut self, bytes: &[u8], on_line: &mut dyn FnMut(FramedLine<'_>)) {
        for &b in bytes {
            if b == b'\n' {
                if self.overlong {
                    on_line(Err(GloveError::Overlong));
                } else if self.len > 0 {
                    on_line(Ok(&self.buf[..self.len]));
                }
                self.len = 0;
                self.overlong = false;
            } else if self.len < MAX_LINE_BYTES {
                self.buf[self.len] = b;
                self.len += 1;
            } else {
                self.overlong = true;
            }
        }
    }

    /// Forgets a partial line (after a disconnect).
    pub fn reset(&mut self) {
        self.len = 0;
        self.overlong = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn decode(line: &str, format: GloveFormat) -> Result<GloveReading, GloveError> {
        let mut r = GloveReading::default();
        decode_line(line.as_bytes(), format, DEFAULT_MAX_VALUE, &mut r).map(|_| r)
    }

    #[test]
    fn alpha_line_with_every_kind_of_key() {
        let r = decode(
            "A100B2048C4095D0E17(AB)2047(BAB)3000F4095G0HP1024JM\r",
            GloveFormat::Alpha,
        )
        .unwrap();
        assert_eq!(
            r.curl,
            [Some(100), Some(2048), Some(4095), Some(0), Some(17)]
        );
        assert_eq!(r.splay[0], Some(2047));
        assert_eq!(r.joint_curl[1], [None, Some(3000), None, None]);
        assert_eq!(r.joystick, [Some(4095), Some(0)]);
        assert_eq!(r.trigger, Some(1024));
        assert_eq!(r.buttons, buttons::JOYSTICK | buttons::A | buttons::PINCH);
        // Joint 1 of the index has its own reading; joint 2 falls back to the finger's.
        assert_eq!(r.joint_raw(1, 1), Some(3000));
        assert_eq!(r.joint_raw(1, 2), Some(2048));
    }

    #[test]
    fn the_protocol_document_examples_decode_as_described() {
        let r = decode(
            "A0B2048C0D0E0(CAA)4095(BB)4095F2047G2047J\n",
            GloveFormat::Alpha,
        )
        .unwrap();
        assert_eq!(r.curl, [Some(0), Some(2048), Some(0), Some(0), Some(0)]);
        assert_eq!(r.joint_curl[2][0], Some(4095));
        assert_eq!(r.splay[1], Some(4095));
        assert_eq!(r.joystick, [Some(2047), Some(2047)]);
        assert_eq!(r.buttons, buttons::A);
        let l = decode("0&2048&0&0&0&2047&2047&0&0&1&0&0&0\n", GloveFormat::Legacy).unwrap();
        assert_eq!(
            (l.curl[1], l.joystick[0], l.buttons),
            (Some(2048), Some(2047), buttons::A)
        );
    }

    #[test]
    fn unknown_keys_are_counted_not_fatal() {
        let r = decode("A5Z9(ZZ)3B6", GloveFormat::Alpha).unwrap();
        assert_eq!(
            (r.curl[0], r.curl[1], r.unknown_keys),
            (Some(5), Some(6), 2)
        );
        assert_eq!(decode("Z1", GloveFormat::Alpha), Err(GloveError::NoData));
    }

    #[test]
    fn bad_alpha_lines_say_where() {
        use GloveError::*;
        let cases = [
            ("", Empty),
            (
                "A1b2",
                BadByte {
                    offset: 2,
                    byte: b'b',
                },
            ),
            ("12A3", ValueWithoutKey { offset: 0 }),
            ("A1(AB", UnclosedKey { offset: 2 }),
            (
                "(A1)5",
                BadByte {
                    offset: 2,
                    byte: b'1',
                },
            ),
            ("A1234567890", TooLong { offset: 1 }),
            (
                "B4096",
                AboveMax {
                    offset: 1,
                    value: 4096,
                    max: 4095,
                },
            ),
        ];
        for (line, want) in cases {
            assert_eq!(decode(line, GloveFormat::Alpha), Err(want), "{line:?}");
        }
    }

    #[test]
    fn legacy_lines() {
        let r = decode("10&20&30&40&50&2047&2048&0&1&0&1&0&1", GloveFormat::Legacy).unwrap();
        assert_eq!(r.curl, [Some(10), Some(20), Some(30), Some(40), Some(50)]);
        assert_eq!(r.joystick, [Some(2047), Some(2048)]);
        assert_eq!(r.buttons, buttons::TRIGGER | buttons::B | buttons::PINCH);
        let short = decode("1&2&3&4&5", GloveFormat::Legacy).unwrap();
        assert_eq!(short.curl[4], Some(5));
        assert_eq!(
            decode("1&2&3&4", GloveFormat::Legacy),
            Err(GloveError::FieldCount { fields: 4 })
        );
        assert!(matches!(
            decode("1&2&x&4&5", GloveFormat::Legacy),
            Err(GloveError::BadField { index: 2, .. })
        ));
        assert_eq!(
            decode("1&2&3&4&5000", GloveFormat::Legacy),
            Err(GloveError::AboveMax {
                offset: 8,
                value: 5000,
                max: 4095
            })
        );
    }

    fn reading() -> impl Strategy<Value = GloveReading> {
        let v = || proptest::option::of(0u32..=DEFAULT_MAX_VALUE);
        (
            proptest::array::uniform5(v()),
            proptest::array::uniform5(proptest::array::uniform4(v())),
            proptest::array::uniform5(v()),
            proptest::array::uniform2(v()),
            v(),
            any::<u8>(),
        )
            .prop_filter("one analog value at least", |(c, _, _, _, _, _)| {
                c.iter().any(Option::is_some)
            })
            .prop_map(
                |(curl, joint_curl, splay, joystick, trigger, b)| GloveReading {
                    curl,
                    joint_curl,
                    splay,
                    joystick,
                    trigger,
                    buttons: u16::from(b),
                    unknown_keys: 0,
                },
            )
    }

    proptest! {
        #[test]
        fn alpha_round_trips(r in reading()) {
            let mut s = String::new();
            encode_alpha(&r, &mut s);
            prop_assert!(s.len() <= MAX_LINE_BYTES);
            prop_assert_eq!(decode(s.trim_end(), GloveFormat::Alpha), Ok(r));
        }

        #[test]
        fn legacy_round_trips(r in reading()) {
            let mut s = String::new();
            encode_legacy(&r, &mut s);
            let back = decode(&s, GloveFormat::Legacy).unwrap();
            let want: Vec<u32> = r.curl.iter().chain(&r.joystick).map(|v| v.unwrap_or(0)).collect();
            let got: Vec<u32> = back.curl.iter().chain(&back.joystick).map(|v| v.unwrap()).collect();
            prop_assert_eq!(got, want);
            prop_assert_eq!(back.buttons, r.buttons & 0x3f);
        }

        #[test]
        fn arbitrary_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..1200)) {
            let mut framer = LineFramer::default();
            let mut r = GloveReading::default();
            let mut lines = 0usize;
            framer.push(&b, &mut |line| {
                lines += 1;
                if let Ok(line) = line {
                    assert!(line.len() <= MAX_LINE_BYTES);
                    let _ = decode_line(line, GloveFormat::Alpha, DEFAULT_MAX_VALUE, &mut r);
                    let _ = decode_line(line, GloveFormat::Legacy, DEFAULT_MAX_VALUE, &mut r);
                }
            });
            prop_assert!(lines <= b.iter().filter(|&&x| x == b'\n').count());
        }

        #[test]
        fn framer_splits_the_same_however_the_bytes_arrive(
            cut in proptest::collection::vec(1usize..40, 1..20),
        ) {
            let text = b"A1B2\nC3\n\nD4E5(AB)6\n";
            let mut whole = Vec::new();
            LineFramer::default().push(text, &mut |l| whole.push(l.map(<[u8]>::to_vec)));
            let mut pieces = Vec::new();
            let mut f = LineFramer::default();
            let mut at = 0;
            for c in cut.iter().cycle() {
                if at >= text.len() { break; }
                let end = (at + c).min(text.len());
                f.push(&text[at..end], &mut |l| pieces.push(l.map(<[u8]>::to_vec)));
                at = end;
            }
            prop_assert_eq!(pieces, whole);
        }
    }

    #[test]
    fn overlong_lines_are_dropped_whole() {
        let mut f = LineFramer::default();
        let mut got = Vec::new();
        let long = vec![b'A'; MAX_LINE_BYTES + 10];
        f.push(&long, &mut |l| got.push(l.map(<[u8]>::to_vec)));
        f.push(b"\nA7\n", &mut |l| got.push(l.map(<[u8]>::to_vec)));
        assert_eq!(got, vec![Err(GloveError::Overlong), Ok(b"A7".to_vec())]);
    }
}
