//! Endpoint URLs, as stage configs, `rigless listen` and `rigless replay --to` name a
//! protocol and its address: `osc://`, `vmc://`, `natnet://`, `vrpn://` and `glove://`.
//! Pure parsing: a string in, an [`Endpoint`] or a [`UrlError`] that says what is wrong.
//! Hosts are numeric (no name lookup here).

use super::glove::{GloveFormat, DEFAULT_MAX_VALUE};
use super::natnet::Version;
use std::net::SocketAddr;
use std::path::PathBuf;

/// Motive's NatNet command port.
pub const NATNET_COMMAND_PORT: u16 = 1510;
/// The VRPN server's default port (TCP and UDP).
pub const VRPN_DEFAULT_PORT: u16 = 3883;

/// How a client reaches a VRPN server.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VrpnMode {
    /// `DEVICE@tcp://HOST:PORT`: the client connects; everything over TCP.
    Tcp,
    /// `DEVICE@HOST[:PORT]`: the server calls back; reports over UDP.
    Udp,
}

/// Serial settings of a data-glove port (8 data bits, no parity, 1 stop bit).
#[derive(Clone, Debug, PartialEq)]
pub struct GlovePort {
    /// The serial device, e.g. `/dev/ttyUSB0`.
    pub path: PathBuf,
    /// Bits per second.
    pub baud: u32,
    /// The line encoding the firmware sends.
    pub format: GloveFormat,
    /// Full-scale reading.
    pub max_value: u32,
}

/// A parsed endpoint URL.
#[derive(Clone, Debug, PartialEq)]
pub enum Endpoint {
    /// `osc://HOST:PORT`: native schema, address patterns and VMC.
    Osc(SocketAddr),
    /// `vmc://HOST:PORT`: VMC only.
    Vmc(SocketAddr),
    /// `natnet://HOST:PORT[?version=M.m&server=IP[:PORT]]`: the data port (a multicast
    /// group or a unicast port); NatNet 3.0 unless the version says otherwise. With a
    /// server, its command port (1510 by default).
    NatNet {
        data: SocketAddr,
        version: Version,
        server: Option<SocketAddr>,
    },
    /// `vrpn://DEVICE@tcp://HOST:PORT` (TCP connection mode) or
    /// `vrpn://DEVICE@HOST[:PORT]` (UDP connection mode; port 3883 by default).
    Vrpn {
        device: String,
        addr: SocketAddr,
        mode: VrpnMode,
    },
    /// `glove:///dev/ttyUSB0[?baud=115200&format=alpha|legacy&max=4095]`.
    Glove(GlovePort),
}

impl Endpoint {
    /// The URL scheme: `osc`, `vmc`, `natnet`, `vrpn` or `glove`.
    pub fn scheme(&self) -> &'static str {
        match self {
            Endpoint::Osc(_) => "osc",
            Endpoint::Vmc(_) => "vmc",
            Endpoint::NatNet { .. } => "natnet",
            Endpoint::Vrpn { .. } => "vrpn",
            Endpoint::Glove(_) => "glove",
        }
    }
}

/// Why a string is not an endpoint URL.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum UrlError {
    #[error("{url:?} is not a URL (expected osc://, vmc://, natnet://HOST:PORT, vrpn://DEVICE@HOST or glove:///PORT)")]
    NotAUrl { url: String },
    #[error("{url:?}: unknown scheme {scheme:?} (expected osc, vmc, natnet, vrpn or glove)")]
    UnknownScheme { url: String, scheme: String },
    #[error("{url:?}: {found:?} is not {expected} with a numeric host (e.g. 127.0.0.1:9000)")]
    Address {
        url: String,
        found: String,
        expected: &'static str,
    },
    #[error("{url:?}: unknown option {option:?} (expected {expected})")]
    UnknownOption {
        url: String,
        option: String,
        expected: &'static str,
    },
    #[error("{url:?}: {key} {value:?} is not {expected}")]
    BadValue {
        url: String,
        key: &'static str,
        value: String,
        expected: &'static str,
    },
    #[error("{url:?}: {what}")]
    Missing { url: String, what: &'static str },
}

/// Parses an endpoint URL, saying what is wrong.
pub fn parse(url: &str) -> Result<Endpoint, UrlError> {
    let (scheme, rest) = url.split_once("://").ok_or_else(|| UrlError::NotAUrl {
        url: url.to_owned(),
    })?;
    let (rest, query) = rest.split_once('?').unwrap_or((rest, ""));
    let options = || query.split('&').filter(|s| !s.is_empty());
    let host_port = |s: &str| -> Result<SocketAddr, UrlError> {
        s.trim_end_matches('/')
            .parse()
            .map_err(|_| UrlError::Address {
                url: url.to_owned(),
                found: s.to_owned(),
                expected: "HOST:PORT",
            })
    };
    match scheme {
        "osc" | "vmc" | "natnet" | "vrpn" | "glove" => {}
        other => {
            return Err(UrlError::UnknownScheme {
                url: url.to_owned(),
                scheme: other.to_owned(),
            })
        }
    }
    if scheme != "natnet" && scheme != "glove" {
        if let Some(option) = options().next() {
            return Err(UrlError::UnknownOption {
                url: url.to_owned(),
                option: option.to_owned(),
                expected: "no options",
            });
        }
    }
    match scheme {
        "osc" => Ok(Endpoint::Osc(host_port(rest)?)),
        "vmc" => Ok(Endpoint::Vmc(host_port(rest)?)),
        "natnet" => natnet(url, host_port(rest)?, options()),
        "vrpn" => vrpn(url, rest),
        _ => glove(url, rest, options()),
    }
}

/// `IP[:PORT]`, the port defaulting to `default_port`.
fn with_default_port(
    url: &str,
    s: &str,
    default_port: u16,
    expected: &'static str,
) -> Result<SocketAddr, UrlError> {
    let with_port = if s.parse::<SocketAddr>().is_ok() {
        s.to_owned()
    } else {
        format!("{s}:{default_port}")
    };
    with_port.parse().map_err(|_| UrlError::Address {
        url: url.to_owned(),
        found: s.to_owned(),
        expected,
    })
}

fn natnet<'a>(
    url: &str,
    data: SocketAddr,
    options: impl Iterator<Item = &'a str>,
) -> Result<Endpoint, UrlError> {
    let mut version = Version(3, 0);
    let mut server = None;
    for kv in options {
        match kv.split_once('=') {
            Some(("server", v)) => {
                server = Some(with_default_port(url, v, NATNET_COMMAND_PORT, "IP[:PORT]")?)
            }
            Some(("version", v)) => {
                let (a, b) = v.split_once('.').unwrap_or((v, "0"));
                version = match (a.parse::<u8>(), b.parse::<u8>()) {
                    (Ok(a), Ok(b)) if (3..=4).contains(&a) => Version(a, b),
                    _ => {
                        return Err(UrlError::BadValue {
                            url: url.to_owned(),
                            key: "version",
                            value: v.to_owned(),
                            expected: "3.x or 4.x",
                        })
                    }
                }
            }
            _ => {
                return Err(UrlError::UnknownOption {
                    url: url.to_owned(),
                    option: kv.to_owned(),
                    expected: "version=M.m or server=IP[:PORT]",
                })
            }
        }
    }
    Ok(Endpoint::NatNet {
        data,
        version,
        server,
    })
}

fn vrpn(url: &str, rest: &str) -> Result<Endpoint, UrlError> {
    let (device, target) = rest.split_once('@').ok_or_else(|| UrlError::Missing {
        url: url.to_owned(),
        what: "expected vrpn://DEVICE@HOST[:PORT] or vrpn://DEVICE@tcp://HOST:PORT (e.g. vrpn://Tracker0@127.0.0.1)",
    })?;
    if device.is_empty() {
        return Err(UrlError::Missing {
            url: url.to_owned(),
            what: "no device name before @",
        });
    }
    let (mode, hp) = match target.strip_prefix("tcp://") {
        Some(hp) => (VrpnMode::Tcp, hp.trim_end_matches('/')),
        None => (VrpnMode::Udp, target.trim_end_matches('/')),
    };
    Ok(Endpoint::Vrpn {
        device: device.to_owned(),
        addr: with_default_port(url, hp, VRPN_DEFAULT_PORT, "HOST[:PORT]")?,
        mode,
    })
}

fn glove<'a>(
    url: &str,
    path: &str,
    options: impl Iterator<Item = &'a str>,
) -> Result<Endpoint, UrlError> {
    if path.is_empty() {
        return Err(UrlError::Missing {
            url: url.to_owned(),
            what: "no port path (e.g. glove:///dev/ttyUSB0?baud=115200&format=alpha)",
        });
    }
    let mut port = GlovePort {
        path: path.into(),
        baud: 115_200,
        format: GloveFormat::Alpha,
        max_value: DEFAULT_MAX_VALUE,
    };
    let positive = |key: &'static str, v: &str| {
        v.parse()
            .ok()
            .filter(|&b: &u32| b > 0)
            .ok_or(UrlError::BadValue {
                url: url.to_owned(),
                key,
                value: v.to_owned(),
                expected: "a positive whole number",
            })
    };
    for kv in options {
        match kv.split_once('=') {
            Some(("baud", v)) => port.baud = positive("baud", v)?,
            Some(("max", v)) => port.max_value = positive("max", v)?,
            Some(("format", "alpha")) => port.format = GloveFormat::Alpha,
            Some(("format", "legacy")) => port.format = GloveFormat::Legacy,
            Some(("format", v)) => {
                return Err(UrlError::BadValue {
                    url: url.to_owned(),
                    key: "format",
                    value: v.to_owned(),
                    expected: "alpha or legacy",
                })
            }
            _ => {
                return Err(UrlError::UnknownOption {
                    url: url.to_owned(),
                    option: kv.to_owned(),
                    expected: "baud=, format= or max=",
                })
            }
        }
    }
    Ok(Endpoint::Glove(port))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn err(url: &str) -> String {
        parse(url).unwrap_err().to_string()
    }

    #[test]
    fn urls_parse_or_say_why_not() {
        assert_eq!(
            parse("osc://127.0.0.1:9000"),
            Ok(Endpoint::Osc("127.0.0.1:9000".parse().unwrap()))
        );
        assert_eq!(
            parse("vmc://127.0.0.1:39539/"),
            Ok(Endpoint::Vmc("127.0.0.1:39539".parse().unwrap()))
        );
        assert_eq!(
            parse("natnet://239.255.42.99:1511?version=4.1"),
            Ok(Endpoint::NatNet {
                data: "239.255.42.99:1511".parse().unwrap(),
                version: Version(4, 1),
                server: None
            })
        );
        assert_eq!(
            parse("natnet://127.0.0.1:1511?server=10.0.0.5"),
            Ok(Endpoint::NatNet {
                data: "127.0.0.1:1511".parse().unwrap(),
                version: Version(3, 0),
                server: Some("10.0.0.5:1510".parse().unwrap())
            })
        );
        assert!(err("natnet://127.0.0.1:1511?version=2.9").contains("3.x or 4.x"));
        assert_eq!(
            parse("vrpn://Tracker0@127.0.0.1"),
            Ok(Endpoint::Vrpn {
                device: "Tracker0".into(),
                addr: "127.0.0.1:3883".parse().unwrap(),
                mode: VrpnMode::Udp,
            })
        );
        assert_eq!(
            parse("vrpn://Spin0@tcp://10.0.0.2:3884"),
            Ok(Endpoint::Vrpn {
                device: "Spin0".into(),
                addr: "10.0.0.2:3884".parse().unwrap(),
                mode: VrpnMode::Tcp,
            })
        );
        assert!(err("vrpn://Tracker0@localhost").contains("numeric host"));
        assert!(err("vrpn://@127.0.0.1").contains("no device name"));
        assert!(err("osc://localhost").contains("HOST:PORT"));
        assert!(err("osc://127.0.0.1:9000?x=1").contains("unknown option"));
        assert!(err("ftp://x").contains("unknown scheme"));
        assert!(err("127.0.0.1:9000").contains("is not a URL"));
        assert_eq!(
            parse("glove:///dev/ttyUSB0?baud=9600&format=legacy&max=1023"),
            Ok(Endpoint::Glove(GlovePort {
                path: "/dev/ttyUSB0".into(),
                baud: 9600,
                format: GloveFormat::Legacy,
                max_value: 1023,
            }))
        );
        assert_eq!(
            parse("glove:///dev/ttyACM1"),
            Ok(Endpoint::Glove(GlovePort {
                path: "/dev/ttyACM1".into(),
                baud: 115_200,
                format: GloveFormat::Alpha,
                max_value: 4095,
            }))
        );
        assert!(err("glove:///dev/x?format=beta").contains("not alpha or legacy"));
        assert!(err("glove:///dev/x?baud=0").contains("positive whole number"));
        assert!(err("glove://").contains("no port path"));
    }

    proptest! {
        /// Any string either parses or says why not; it never panics, and a parsed
        /// endpoint's scheme is the one written.
        #[test]
        fn any_string_parses_or_is_refused(s in ".{0,80}", scheme in "(osc|vmc|natnet|vrpn|glove|x)://") {
            let url = format!("{scheme}{s}");
            if let Ok(e) = parse(&url) {
                prop_assert_eq!(format!("{}://", e.scheme()), scheme);
            }
            if let Err(e) = parse(&s) {
                prop_assert!(!e.to_string().is_empty());
            }
        }
    }
}
