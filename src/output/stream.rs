//! The vertex stream server, over TCP and over WebSocket (each on its own port): each
//! client gets the topology, then every solved frame in the format of
//! `protocols/vertex-stream.md`, and a goodbye at shutdown. Over WebSocket every message
//! is one binary WebSocket message holding exactly the same bytes. The WebSocket port
//! also serves the browser viewer's page ([`super::viewer`]): a request there that does
//! not ask for an upgrade gets the page and is closed, and does not count as a client.
//!
//! Runs on its own thread with a single-threaded tokio runtime. The solver publishes into
//! a [`LatestSlot`]; a dispatcher task encodes each frame once and puts the bytes into a
//! `watch` channel that every client task follows, so a slow client skips to the newest frame (the skipped frames
//! are counted) and never holds up the loop or the other clients.
//!
//! At most `max_clients` are served at once (a connection still in its WebSocket
//! handshake counts); the next is sent a goodbye saying the server is full and closed.
//! When accepting fails (out of file descriptors, say), the server waits before it tries
//! again, 100 ms and doubling up to a second, and says so at most once a second with a
//! count of the failures it did not report; the clients already connected are served
//! meanwhile.

use super::config::StreamOutputConfig;
use super::frame::DeformedFrame;
use super::viewer::{bad_request, head_end, parse_head, respond, MAX_HEAD_BYTES};
use crate::protocol::vertex_stream::{encode_frame, encode_goodbye, encode_topology, Topology};
use crate::runtime::said::Throttle;
use crate::runtime::slot::LatestSlot;
use futures_util::SinkExt;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::thread::JoinHandle;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinSet;
use tokio_tungstenite::tungstenite::Message as WsMessage;
use tokio_tungstenite::WebSocketStream;

/// A client whose socket accepts nothing for this long is disconnected, seconds.
pub const WRITE_TIMEOUT_SECS: f64 = 5.0;
/// How long shutdown waits for clients to take their goodbye, seconds; also each step
/// of refusing a connection (handshake, goodbye, close).
const GOODBYE_TIMEOUT_SECS: f64 = 1.0;
/// Connections being refused at once at most; beyond, a connection is closed at once,
/// with no goodbye.
const MAX_REFUSALS: usize = 16;
/// The first wait after a failed accept, seconds; it doubles with each failure in a row
/// up to [`ACCEPT_BACKOFF_MAX_S`].
const ACCEPT_BACKOFF_MIN_S: f64 = 0.1;
/// The longest wait after failed accepts, seconds.
const ACCEPT_BACKOFF_MAX_S: f64 = 1.0;
/// Seconds between two lines about failing accepts.
const ACCEPT_REPORT_INTERVAL_S: f64 = 1.0;

/// What the server has done (monotonic except `clients`).
#[derive(Debug, Default)]
pub struct StreamStats {
    /// Clients connected now.
    pub clients: AtomicU64,
    /// Connections accepted to be served, in all (refused ones are not counted).
    pub connections: AtomicU64,
    /// Connections refused because `max_clients` were connected (sent a goodbye saying
    /// so, when no more than [`MAX_REFUSALS`] were being refused, and closed).
    pub refused: AtomicU64,
    /// Accepts that failed (out of file descriptors, ...); each made the server wait.
    pub accept_errors: AtomicU64,
    /// Frame messages written, over all clients.
    pub frames_sent: AtomicU64,
    /// Frames a client skipped because it was slower than the loop, over all clients.
    pub frames_skipped: AtomicU64,
    /// Clients dropped on a write error or timeout (a client that hangs up is noticed
    /// at the next write, so it counts here too; so does one whose goodbye fails).
    pub write_errors: AtomicU64,
    /// WebSocket connections whose handshake failed or timed out (a request head that
    /// does not parse included).
    pub handshake_errors: AtomicU64,
    /// Requests on the WebSocket port answered with the viewer's page (or a 404); they
    /// are not counted in `connections`.
    pub pages_served: AtomicU64,
}

/// A frame encoded once for every client: its number and its message bytes.
struct Encoded {
    frame: u64,
    bytes: Vec<u8>,
}

type FrameRx = watch::Receiver<Option<Arc<Encoded>>>;
type ShutdownRx = watch::Receiver<Option<String>>;

/// A running vertex stream server.
pub struct StreamServer {
    local_addr: Option<SocketAddr>,
    ws_addr: Option<SocketAddr>,
    shutdown: watch::Sender<Option<String>>,
    thread: Option<JoinHandle<()>>,
    stats: Arc<StreamStats>,
}

impl StreamServer {
    /// Binds `cfg.tcp` and `cfg.websocket` (either may be `None`; port 0 picks a free
    /// port) and serves frames published to `slot` to at most `cfg.max_clients` clients.
    pub fn start(
        cfg: &StreamOutputConfig,
        topology: &Topology,
        slot: Arc<LatestSlot<DeformedFrame>>,
    ) -> io::Result<Self> {
        let (tcp, ws, max_clients) = (cfg.tcp, cfg.websocket, cfg.max_clients.max(1));
        let viewer = cfg.viewer;
        let bind = |a: Option<SocketAddr>| -> io::Result<Option<std::net::TcpListener>> {
            a.map(|a| {
                let l = std::net::TcpListener::bind(a)?;
                l.set_nonblocking(true)?;
                Ok(l)
            })
            .transpose()
        };
        let ws_l = match bind(ws) {
            Err(e) if e.kind() == io::ErrorKind::AddrInUse && cfg.websocket_any_port_if_taken => {
                let taken = ws.expect("a WebSocket address was bound");
                tracing::info!("{taken} is taken: the WebSocket and the viewer take a free port");
                bind(Some(SocketAddr::new(taken.ip(), 0)))?
            }
            r => r?,
        };
        let tcp_l = bind(tcp)?;
        let local_addr = tcp_l.as_ref().map(|l| l.local_addr()).transpose()?;
        let ws_addr = ws_l.as_ref().map(|l| l.local_addr()).transpose()?;
        let mut topo = Vec::new();
        encode_topology(topology, &mut topo);
        let topo = Arc::new(topo);
        let stats = Arc::new(StreamStats::default());
        let (shutdown, shutdown_rx) = watch::channel(None);
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?;
        let thread_stats = Arc::clone(&stats);
        let thread = std::thread::Builder::new()
            .name("vertex-stream".into())
            .spawn(move || {
                let listeners = Listeners {
                    tcp: tcp_l,
                    ws: ws_l,
                    max_clients,
                    viewer,
                };
                rt.block_on(serve(listeners, topo, slot, shutdown_rx, thread_stats));
            })?;
        Ok(Self {
            local_addr,
            ws_addr,
            shutdown,
            thread: Some(thread),
            stats,
        })
    }

    /// The TCP listener's address, if serving TCP.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.local_addr
    }

    /// The WebSocket listener's address, if serving WebSocket.
    pub fn ws_addr(&self) -> Option<SocketAddr> {
        self.ws_addr
    }

    pub fn stats(&self) -> &Arc<StreamStats> {
        &self.stats
    }

    /// Sends every client a goodbye with `reason`, closes, and waits for the thread.
    pub fn shutdown(mut self, reason: &str) {
        self.stop(reason);
    }

    fn stop(&mut self, reason: &str) {
        self.shutdown.send_replace(Some(reason.to_owned()));
        if let Some(t) = self.thread.take() {
            // The thread ends within GOODBYE_TIMEOUT_SECS; a panic there printed its
            // message through the panic hook, and here says what it cost.
            if t.join().is_err() {
                tracing::error!(
                    "the stream server's thread panicked: clients were not told goodbye"
                );
            }
        }
    }
}

impl Drop for StreamServer {
    fn drop(&mut self) {
        if self.thread.is_some() {
            self.stop("server dropped");
        }
    }
}

/// A connected client of either transport.
enum Conn {
    Tcp(TcpStream),
    Ws(Box<WebSocketStream<Rewind>>),
}

/// What an accepted socket turned out to be.
enum Accepted {
    Client(Conn),
    /// A request on the WebSocket port that was not an upgrade: answered and closed.
    Page,
    /// A WebSocket handshake that failed or took too long.
    Failed,
}

/// A socket whose first bytes were already read (the request head): they are read again
/// before the socket's own, so the WebSocket handshake sees the whole request.
struct Rewind {
    prefix: Vec<u8>,
    at: usize,
    inner: TcpStream,
}

impl AsyncRead for Rewind {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let me = &mut *self;
        if me.at < me.prefix.len() {
            let n = buf.remaining().min(me.prefix.len() - me.at);
            buf.put_slice(&me.prefix[me.at..me.at + n]);
            me.at += n;
            return Poll::Ready(Ok(()));
        }
        Pin::new(&mut me.inner).poll_read(cx, buf)
    }
}

impl AsyncWrite for Rewind {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// Reads a request head from `sock`: the bytes up to its blank line and whatever came
/// with them, at most [`MAX_HEAD_BYTES`]. `None` if the peer closes first or sends more
/// without ending its head.
async fn read_head(sock: &mut TcpStream) -> Option<(Vec<u8>, usize)> {
    let mut buf = vec![0u8; MAX_HEAD_BYTES];
    let mut have = 0;
    while have < buf.len() {
        let n = sock.read(&mut buf[have..]).await.ok()?;
        if n == 0 {
            return None;
        }
        // The blank line may straddle two reads: look from three bytes before.
        let from = have.saturating_sub(3);
        have += n;
        if let Some(end) = head_end(&buf[from..have]) {
            buf.truncate(have);
            return Some((buf, from + end));
        }
    }
    None
}

impl Conn {
    /// What an accepted socket is: over WebSocket, a client once its handshake is done,
    /// or a page request, answered when `viewer` (else refused with a 404); each bounded
    /// by `limit`.
    async fn accept(sock: TcpStream, websocket: bool, viewer: bool, limit: Duration) -> Accepted {
        if !websocket {
            return Accepted::Client(Conn::Tcp(sock));
        }
        let handshake = async move {
            let mut sock = sock;
            let (bytes, end) = read_head(&mut sock).await?;
            let reply = match parse_head(&bytes[..end]) {
                Ok(h) if h.websocket => {
                    let rewind = Rewind {
                        prefix: bytes,
                        at: 0,
                        inner: sock,
                    };
                    let ws = tokio_tungstenite::accept_async(rewind).await.ok()?;
                    return Some(Accepted::Client(Conn::Ws(Box::new(ws))));
                }
                Ok(h) => respond(&h, viewer),
                Err(e) => bad_request(&e),
            };
            sock.write_all(&reply).await.ok()?;
            // The peer reads to the end: close our side, and let it go.
            sock.shutdown().await.ok()?;
            Some(Accepted::Page)
        };
        match tokio::time::timeout(limit, handshake).await {
            Ok(Some(a)) => a,
            _ => Accepted::Failed,
        }
    }

    /// Sends one message; false on error or timeout.
    async fn send(&mut self, bytes: &[u8], secs: f64) -> bool {
        let limit = Duration::from_secs_f64(secs);
        match self {
            Conn::Tcp(s) => matches!(
                tokio::time::timeout(limit, s.write_all(bytes)).await,
                Ok(Ok(()))
            ),
            Conn::Ws(w) => {
                let msg = WsMessage::binary(bytes.to_vec());
                matches!(tokio::time::timeout(limit, w.send(msg)).await, Ok(Ok(())))
            }
        }
    }

    async fn close(&mut self) {
        let limit = Duration::from_secs_f64(GOODBYE_TIMEOUT_SECS);
        let closed = match self {
            Conn::Tcp(s) => matches!(tokio::time::timeout(limit, s.shutdown()).await, Ok(Ok(()))),
            // The WebSocket close handshake (the stream's own `close`, not `SinkExt::close`).
            Conn::Ws(w) => matches!(
                tokio::time::timeout(limit, WebSocketStream::close(&mut **w, None)).await,
                Ok(Ok(()))
            ),
        };
        // The goodbye was written; a client that hung up before the close costs nothing.
        if !closed {
            tracing::debug!(
                "a stream client's connection did not close cleanly (an error, or not within {limit:?})"
            );
        }
    }
}

async fn accept_on(l: &Option<TcpListener>) -> io::Result<(TcpStream, SocketAddr)> {
    match l {
        Some(l) => l.accept().await,
        None => std::future::pending().await,
    }
}

/// The listening sockets, how many clients they may serve at once, and whether the
/// WebSocket port serves the viewer's page.
struct Listeners {
    tcp: Option<std::net::TcpListener>,
    ws: Option<std::net::TcpListener>,
    max_clients: usize,
    viewer: bool,
}

/// How long the accept loop waits after failures in a row: [`ACCEPT_BACKOFF_MIN_S`],
/// doubling up to [`ACCEPT_BACKOFF_MAX_S`], and back to the start after a success.
#[derive(Clone, Debug)]
struct AcceptBackoff {
    next_s: f64,
}

impl Default for AcceptBackoff {
    fn default() -> Self {
        Self {
            next_s: ACCEPT_BACKOFF_MIN_S,
        }
    }
}

impl AcceptBackoff {
    /// An accept failed: the wait before the next, seconds.
    fn failed(&mut self) -> f64 {
        let wait = self.next_s;
        self.next_s = (wait * 2.0).min(ACCEPT_BACKOFF_MAX_S);
        wait
    }

    fn succeeded(&mut self) {
        *self = Self::default();
    }
}

async fn serve(
    listeners: Listeners,
    topo: Arc<Vec<u8>>,
    slot: Arc<LatestSlot<DeformedFrame>>,
    mut shutdown: ShutdownRx,
    stats: Arc<StreamStats>,
) {
    let register = |l: Option<std::net::TcpListener>| match l.map(TcpListener::from_std) {
        None => None,
        Some(Ok(l)) => Some(l),
        Some(Err(e)) => {
            tracing::error!(error = %e, "vertex stream: cannot register a listener");
            None
        }
    };
    let (max_clients, viewer) = (listeners.max_clients, listeners.viewer);
    let (tcp, ws) = (register(listeners.tcp), register(listeners.ws));
    let (frames_tx, frames_rx) = watch::channel(None);
    let dispatcher = tokio::spawn(dispatch(slot, frames_tx, shutdown.clone()));
    let mut full = Vec::new();
    encode_goodbye(
        &format!("server full: {max_clients} clients connected (its max_clients)"),
        &mut full,
    );
    let full = Arc::new(full);
    let (mut clients, mut refusals) = (JoinSet::new(), JoinSet::new());
    let (mut backoff, mut report) = (
        AcceptBackoff::default(),
        Throttle::new(ACCEPT_REPORT_INTERVAL_S),
    );
    let started = tokio::time::Instant::now();
    let mut paused_until: Option<tokio::time::Instant> = None;
    loop {
        let (r, websocket) = tokio::select! {
            r = accept_on(&tcp), if paused_until.is_none() => (r, false),
            r = accept_on(&ws), if paused_until.is_none() => (r, true),
            _ = tokio::time::sleep_until(paused_until.unwrap_or(started)), if paused_until.is_some() => {
                paused_until = None;
                continue;
            }
            _ = shutdown.changed() => break,
            Some(_) = clients.join_next(), if !clients.is_empty() => continue,
            Some(_) = refusals.join_next(), if !refusals.is_empty() => continue,
        };
        let (sock, peer) = match r {
            Ok(x) => x,
            Err(e) => {
                stats.accept_errors.fetch_add(1, Ordering::Relaxed);
                let wait_s = backoff.failed();
                if let Some(unsaid) = report.hit(started.elapsed().as_secs_f64()) {
                    let since = match unsaid {
                        0 => String::new(),
                        n => format!(" ({n} more failures since the last line)"),
                    };
                    tracing::warn!(
                        "vertex stream: accepting a connection failed: {e}; trying again in {:.0} ms{since}",
                        wait_s * 1e3
                    );
                }
                paused_until = Some(tokio::time::Instant::now() + Duration::from_secs_f64(wait_s));
                continue;
            }
        };
        backoff.succeeded();
        while clients.try_join_next().is_some() {}
        if clients.len() >= max_clients {
            stats.refused.fetch_add(1, Ordering::Relaxed);
            tracing::debug!(%peer, websocket, "vertex stream: refused, full");
            if refusals.len() < MAX_REFUSALS {
                refusals.spawn(refuse(sock, websocket, viewer, Arc::clone(&full)));
            }
            continue;
        }
        stats.connections.fetch_add(1, Ordering::Relaxed);
        tracing::debug!(%peer, websocket, "vertex stream: client connected");
        let (topo, frames, shutdown, stats) = (
            Arc::clone(&topo),
            frames_rx.clone(),
            shutdown.clone(),
            Arc::clone(&stats),
        );
        clients.spawn(async move {
            if let Err(e) = sock.set_nodelay(true) {
                tracing::debug!("TCP_NODELAY not set on a stream client: {e}");
            }
            let limit = Duration::from_secs_f64(WRITE_TIMEOUT_SECS);
            match Conn::accept(sock, websocket, viewer, limit).await {
                Accepted::Client(conn) => serve_client(conn, topo, frames, shutdown, stats).await,
                Accepted::Page => {
                    stats.connections.fetch_sub(1, Ordering::Relaxed);
                    stats.pages_served.fetch_add(1, Ordering::Relaxed);
                }
                Accepted::Failed => {
                    stats.handshake_errors.fetch_add(1, Ordering::Relaxed);
                }
            }
        });
    }
    drop((tcp, ws, refusals));
    if let Err(e) = dispatcher.await {
        tracing::error!("the stream's frame dispatcher failed: {e}");
    }
    let goodbye_limit = Duration::from_secs_f64(GOODBYE_TIMEOUT_SECS * 2.0);
    let all_said = tokio::time::timeout(goodbye_limit, async {
        while clients.join_next().await.is_some() {}
    })
    .await;
    if all_said.is_err() {
        // Dropping the set aborts them.
        tracing::warn!(
            "{} stream connections still open {goodbye_limit:?} after the goodbye; they are cut",
            clients.len()
        );
    }
}

/// Encodes each frame published to `slot` once and hands the bytes to every client,
/// until shutdown.
async fn dispatch(
    slot: Arc<LatestSlot<DeformedFrame>>,
    frames_tx: watch::Sender<Option<Arc<Encoded>>>,
    mut shutdown: ShutdownRx,
) {
    loop {
        tokio::select! {
            f = slot.next() => {
                let mut bytes = Vec::with_capacity(64 + 12 * f.vertices_m.len());
                encode_frame(&f.wire(), &mut bytes);
                let e = Encoded { frame: f.frame, bytes };
                drop(f);
                frames_tx.send_replace(Some(Arc::new(e)));
            }
            _ = shutdown.changed() => break,
        }
    }
}

/// Sends a connection the server had no room for the `goodbye` (after the WebSocket
/// handshake, over WebSocket) and closes it; each step bounded by
/// [`GOODBYE_TIMEOUT_SECS`].
async fn refuse(sock: TcpStream, websocket: bool, viewer: bool, goodbye: Arc<Vec<u8>>) {
    let limit = Duration::from_secs_f64(GOODBYE_TIMEOUT_SECS);
    if let Accepted::Client(mut conn) = Conn::accept(sock, websocket, viewer, limit).await {
        if conn.send(&goodbye, GOODBYE_TIMEOUT_SECS).await {
            conn.close().await;
        }
    }
}

async fn serve_client(
    mut conn: Conn,
    topo: Arc<Vec<u8>>,
    mut frames: FrameRx,
    mut shutdown: ShutdownRx,
    stats: Arc<StreamStats>,
) {
    stats.clients.fetch_add(1, Ordering::Relaxed);
    let mut ok = conn.send(&topo, WRITE_TIMEOUT_SECS).await;
    // Send the newest frame at once rather than waiting for the next.
    frames.mark_changed();
    let mut buf = Vec::new();
    let mut last: Option<u64> = None;
    while ok {
        tokio::select! {
            biased;
            _ = shutdown.changed() => break,
            r = frames.changed() => {
                if r.is_err() {
                    // The dispatcher has gone: the server is shutting down. Wait for
                    // its reason (an error means the server itself has gone, which ends
                    // the client all the same); the guard it returns is let go at once.
                    drop(shutdown.wait_for(Option::is_some).await);
                    break;
                }
                let Some(f) = frames.borrow_and_update().clone() else { continue };
                if let Some(l) = last {
                    let skipped = f.frame.saturating_sub(l + 1);
                    stats.frames_skipped.fetch_add(skipped, Ordering::Relaxed);
                }
                last = Some(f.frame);
                ok = conn.send(&f.bytes, WRITE_TIMEOUT_SECS).await;
                if ok {
                    stats.frames_sent.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
    if ok {
        let reason = shutdown.borrow().clone().unwrap_or_default();
        buf.clear();
        encode_goodbye(&reason, &mut buf);
        ok = conn.send(&buf, GOODBYE_TIMEOUT_SECS).await;
        if ok {
            conn.close().await;
        }
    }
    if !ok {
        stats.write_errors.fetch_add(1, Ordering::Relaxed);
    }
    stats.clients.fetch_sub(1, Ordering::Relaxed);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_accepts_wait_longer_up_to_a_second_and_a_success_starts_over() {
        let mut b = AcceptBackoff::default();
        let waits: Vec<f64> = (0..6).map(|_| b.failed()).collect();
        assert_eq!(waits, [0.1, 0.2, 0.4, 0.8, 1.0, 1.0]);
        b.succeeded();
        assert_eq!(b.failed(), 0.1);
    }
}
