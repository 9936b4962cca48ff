//! The browser viewer: its page (`viewer/index.html`, `viewer/viewer.js` and
//! `viewer/decode.js`, WebGL 2 with no library, built into the binary) and the HTTP it
//! is served with, as pure functions over bytes. The vertex stream's WebSocket port
//! serves it: a request that asks for a WebSocket upgrade becomes a stream client, any
//! other gets the page ([`super::stream`] does the I/O). The page decodes `protocols/vertex-stream.md`
//! itself and reconnects on its own.

/// The page.
pub const INDEX_HTML: &str = include_str!("viewer/index.html");
/// The page's script: renderer, camera, overlay and connection.
pub const VIEWER_JS: &str = include_str!("viewer/viewer.js");
/// The page's decoder of the vertex stream (a module of its own, so that it runs under
/// Node.js in tests too).
pub const DECODE_JS: &str = include_str!("viewer/decode.js");

/// Longest request head read before it is refused, bytes (a browser's is under 2 KiB).
pub const MAX_HEAD_BYTES: usize = 8192;

/// What a request head asks for.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RequestHead {
    /// `GET`, `HEAD`, ... as sent.
    pub method: String,
    /// The path, without the query string.
    pub path: String,
    /// Whether it asks for a WebSocket upgrade (`Upgrade: websocket`).
    pub websocket: bool,
}

/// Why bytes are not a request head.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum HeadError {
    #[error("the request line {line:?} is not `METHOD PATH HTTP/1.x`")]
    RequestLine { line: String },
    #[error("header line {index} has no colon")]
    Header { index: usize },
    #[error("the head is not UTF-8")]
    NotText,
    #[error("the head is longer than {MAX_HEAD_BYTES} bytes")]
    TooLong,
}

/// Where a head ends in `buf`: the index just past its blank line, if it has one. Lines
/// end in CRLF or, as RFC 9112 §2.2 lets a recipient read them, a bare LF.
pub fn head_end(buf: &[u8]) -> Option<usize> {
    buf.iter().enumerate().find_map(|(i, &b)| {
        if b != b'\n' {
            return None;
        }
        match (buf.get(i + 1), buf.get(i + 2)) {
            (Some(b'\n'), _) => Some(i + 2),
            (Some(b'\r'), Some(b'\n')) => Some(i + 3),
            _ => None,
        }
    })
}

/// Parses a request head (the bytes up to and including its blank line; lines end in
/// CRLF or a bare LF).
pub fn parse_head(head: &[u8]) -> Result<RequestHead, HeadError> {
    let text = std::str::from_utf8(head).map_err(|_| HeadError::NotText)?;
    let mut lines = text.split('\n').map(|l| l.strip_suffix('\r').unwrap_or(l));
    let first = lines.next().unwrap_or_default();
    let mut words = first.split(' ');
    let (Some(method), Some(target), Some(version), None) =
        (words.next(), words.next(), words.next(), words.next())
    else {
        return Err(HeadError::RequestLine {
            line: first.chars().take(80).collect(),
        });
    };
    if method.is_empty() || !target.starts_with('/') || !version.starts_with("HTTP/1.") {
        return Err(HeadError::RequestLine {
            line: first.chars().take(80).collect(),
        });
    }
    let mut websocket = false;
    for (index, line) in lines.enumerate().take_while(|(_, l)| !l.is_empty()) {
        let (name, value) = line
            .split_once(':')
            .ok_or(HeadError::Header { index: index + 1 })?;
        if name.trim().eq_ignore_ascii_case("upgrade") {
            websocket |= value
                .split(',')
                .any(|v| v.trim().eq_ignore_ascii_case("websocket"));
        }
    }
    let path = target.split(['?', '#']).next().unwrap_or("/");
    Ok(RequestHead {
        method: method.to_owned(),
        path: path.to_owned(),
        websocket,
    })
}

/// The whole HTTP response to a page request (the connection is closed after it); with
/// `page` false (`[outputs.stream] viewer = false`) every path is not found.
pub fn respond(req: &RequestHead, page: bool) -> Vec<u8> {
    let path = if page { req.path.as_str() } else { "" };
    let (status, kind, body): (&str, &str, &str) = match (req.method.as_str(), path) {
        ("GET" | "HEAD", "/" | "/index.html") => ("200 OK", "text/html; charset=utf-8", INDEX_HTML),
        ("GET" | "HEAD", "/viewer.js") => ("200 OK", "text/javascript; charset=utf-8", VIEWER_JS),
        ("GET" | "HEAD", "/decode.js") => ("200 OK", "text/javascript; charset=utf-8", DECODE_JS),
        ("GET" | "HEAD", _) => ("404 Not Found", "text/plain; charset=utf-8", "not found\n"),
        _ => (
            "405 Method Not Allowed",
            "text/plain; charset=utf-8",
            "only GET and HEAD\n",
        ),
    };
    let mut out = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n",
        body.len()
    )
    .into_bytes();
    if req.method != "HEAD" {
        out.extend_from_slice(body.as_bytes());
    }
    out
}

/// The response to a head that does not parse, or is longer than [`MAX_HEAD_BYTES`].
pub fn bad_request(e: &HeadError) -> Vec<u8> {
    let body = format!("{e}\n");
    format!(
        "HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn head(text: &str) -> Result<RequestHead, HeadError> {
        parse_head(text.as_bytes())
    }

    #[test]
    fn a_browser_gets_the_page_and_a_websocket_client_is_told_apart() {
        let page =
            head("GET /?x=1 HTTP/1.1\r\nHost: 127.0.0.1:7879\r\nAccept: */*\r\n\r\n").unwrap();
        assert_eq!(page.path, "/");
        assert!(!page.websocket);
        let r = String::from_utf8(respond(&page, true)).unwrap();
        assert!(r.starts_with("HTTP/1.1 200 OK\r\n"), "{r}");
        assert!(r.contains(&format!("Content-Length: {}\r\n", INDEX_HTML.len())));
        assert!(r.ends_with(INDEX_HTML));
        let ws = head(
            "GET /stream HTTP/1.1\r\nHost: a\r\nConnection: Upgrade\r\nupgrade: WebSocket\r\n\r\n",
        )
        .unwrap();
        assert!(ws.websocket);
        let js = head("HEAD /viewer.js HTTP/1.0\r\n\r\n").unwrap();
        let r = String::from_utf8(respond(&js, true)).unwrap();
        assert!(
            r.contains("text/javascript") && r.ends_with("\r\n\r\n"),
            "{r}"
        );
        let r = String::from_utf8(respond(
            &head("GET /etc/passwd HTTP/1.1\r\n\r\n").unwrap(),
            true,
        ))
        .unwrap();
        assert!(r.starts_with("HTTP/1.1 404"), "{r}");
        let r =
            String::from_utf8(respond(&head("POST / HTTP/1.1\r\n\r\n").unwrap(), true)).unwrap();
        assert!(r.starts_with("HTTP/1.1 405"), "{r}");
        let r = String::from_utf8(respond(&page, false)).unwrap();
        assert!(r.starts_with("HTTP/1.1 404"), "the viewer is off: {r}");
    }

    #[test]
    fn malformed_heads_are_refused_with_the_reason() {
        assert!(matches!(
            head("GET\r\n\r\n"),
            Err(HeadError::RequestLine { .. })
        ));
        assert!(matches!(
            head("GET x HTTP/1.1\r\n\r\n"),
            Err(HeadError::RequestLine { .. })
        ));
        assert!(matches!(
            head("GET / SPDY/3\r\n\r\n"),
            Err(HeadError::RequestLine { .. })
        ));
        assert_eq!(
            head("GET / HTTP/1.1\r\nHost a\r\n\r\n"),
            Err(HeadError::Header { index: 1 })
        );
        assert_eq!(
            parse_head(b"GET / HTTP/1.1\r\n\xff\r\n\r\n"),
            Err(HeadError::NotText)
        );
        let r = String::from_utf8(bad_request(&HeadError::NotText)).unwrap();
        assert!(r.starts_with("HTTP/1.1 400") && r.ends_with("the head is not UTF-8\n"));
    }

    /// A head whose lines end in a bare LF (RFC 9112 §2.2) ends at its blank line and
    /// parses as the CRLF one does; a blank line that straddles the two endings too.
    #[test]
    fn bare_lf_heads_end_and_parse() {
        assert_eq!(head_end(b"GET / HTTP/1.1\r\nHost: a\r\n\r\nrest"), Some(27));
        assert_eq!(head_end(b"GET / HTTP/1.1\nHost: a\n\nrest"), Some(24));
        assert_eq!(head_end(b"GET / HTTP/1.1\nHost: a\n\r\n"), Some(25));
        assert_eq!(head_end(b"GET / HTTP/1.1\r\nHost: a\r\n"), None);
        let lf = head("GET /viewer.js HTTP/1.1\nHost: a\nUpgrade: websocket\n\n").unwrap();
        assert_eq!(lf.path, "/viewer.js");
        assert!(lf.websocket);
    }

    #[test]
    fn the_page_refers_to_its_scripts_and_the_decoder_reads_version_4() {
        assert!(INDEX_HTML.contains("viewer.js"));
        assert!(VIEWER_JS.contains("from \"./decode.js\""));
        assert!(
            DECODE_JS.contains("version > 4"),
            "the page must refuse versions it does not know"
        );
        let js = parse_head(b"GET /decode.js HTTP/1.1\r\n\r\n").unwrap();
        let r = String::from_utf8(respond(&js, true)).unwrap();
        assert!(r.starts_with("HTTP/1.1 200 OK") && r.ends_with(DECODE_JS));
    }

    proptest! {
        /// Arbitrary bytes never panic the parser, and a head that parses and is
        /// answered gives a response whose length header tells its body's length.
        #[test]
        fn arbitrary_heads_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
            let _ = head_end(&bytes);
            if let Ok(h) = parse_head(&bytes) {
                let r = respond(&h, true);
                let split = head_end(&r).expect("a response has a head");
                let text = String::from_utf8_lossy(&r[..split]).to_string();
                let len: usize = text
                    .lines()
                    .find_map(|l| l.strip_prefix("Content-Length: "))
                    .expect("a length")
                    .parse()
                    .unwrap();
                prop_assert!(r.len() == split + len || (h.method == "HEAD" && r.len() == split));
            }
        }

        /// Arbitrary methods, paths and header values in a well-formed head.
        #[test]
        fn arbitrary_header_values_parse(
            path in "/[a-z0-9./?=&%-]{0,40}",
            value in "[ -~]{0,60}",
            upgrade in proptest::bool::ANY,
        ) {
            let up = if upgrade { "Upgrade: websocket\r\n" } else { "" };
            let text = format!("GET {path} HTTP/1.1\r\nX-Any: {value}\r\n{up}\r\n");
            let h = head(&text).unwrap();
            prop_assert_eq!(h.websocket, upgrade);
            prop_assert!(h.path.starts_with('/'));
        }
    }
}
