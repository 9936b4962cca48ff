//! The vertex stream server, over TCP and over WebSocket (each on its own port): each
//! client gets the topology, then every solved frame in the format of
//! `protocols/vertex-stream.md`, and a goodbye at shutdown. Over WebSocket every message
//! is one binary WebSocket message holding exactly the same bytes. The WebSocket port
//! also serves the browser viewer's page ([`super::viewer`]): a request there that does
//! not ask for an upgrade gets the page and is closed, and does not count as a client.
//!
//! A stage of several actors streams them all on one connection: a topology per actor
//! (in the stage's order), then each actor's frames, tagged with its index.
//!
//! Runs on its own thread with a single-threaded tokio runtime. Each actor's solver
//! publishes into its own [`LatestSlot`]; a dispatcher task per actor encodes each frame
//! once and puts the bytes into that actor's place in a `watch` channel that every
//! client task follows, so a slow client skips to each actor's newest frame (the skipped
//! frames are counted) and never holds up the loop or the other clients.
//!
//! At most `max_clients` are served at once; the next is sent a goodbye saying the server
//! is full and closed. A connection to the WebSocket port is no client until its
//! handshake is done: requests still being read, and pages, have their own budget
//! ([`MAX_HANDSHAKES`], the oldest cut when it is spent) and a short deadline for the
//! head ([`HEAD_TIMEOUT_SECS`]), so half-sent heads never take a client's place. A
//! WebSocket client's pings get pongs and its close gets a close (RFC 6455 §5.5).
//! When accepting fails (out of file descriptors, say), the server waits before it tries
//! again, 100 ms and doubling up to a second, and says so at most once a second with a
//! count of the failures it did not report; the clients already connected are served
//! meanwhile.

use super::config::StreamOutputConfig;
use super::frame::DeformedFrame;
use super::viewer::{bad_request, head_end, parse_head, respond, HeadError, MAX_HEAD_BYTES};
use crate::protocol::vertex_stream::{encode_frame, encode_goodbye, encode_topology, Topology};
use crate::runtime::said::Throttle;
use crate::runtime::slot::LatestSlot;
use futures_util::{SinkExt, StreamExt};
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
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
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
/// Connections to the WebSocket port still in their request or handshake, or being sent
/// a page, at once at most. When they are all under way, new connections wait in the
/// listen queue until one ends or the oldest has had [`HANDSHAKE_GRACE_SECS`]; then it
/// is cut to make room.
pub const MAX_HANDSHAKES: usize = 32;
/// Time a handshake keeps its place against newcomers, seconds (one on loopback or a
/// LAN takes well under a millisecond; a burst of clients waits, a slowloris loses).
pub const HANDSHAKE_GRACE_SECS: f64 = 0.25;
/// Time a connection to the WebSocket port has to send its request head, seconds (a
/// browser sends it at once).
pub const HEAD_TIMEOUT_SECS: f64 = 2.0;
/// Largest message or frame a WebSocket client may send, bytes: it has nothing to send
/// but pings and a close.
const WS_MAX_MESSAGE_BYTES: usize = 64 << 10;
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
    /// Clients dropped on a write error or timeout (a TCP client that hangs up is
    /// noticed at the next write, so it counts here too; so does one whose goodbye
    /// fails; a WebSocket client's close or hang-up is read, and is no error).
    pub write_errors: AtomicU64,
    /// WebSocket-port connections whose handshake failed, timed out or was cut to make
    /// room (a request head that does not parse is answered and counted as a page).
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

/// Each actor's newest encoded frame (`None` before its first).
type Newest = Vec<Option<Arc<Encoded>>>;
type FrameRx = watch::Receiver<Newest>;
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
    /// port) and serves to at most `cfg.max_clients` clients each actor's `topologies[i]`
    /// and the frames published to its `slots[i]` (one of each per actor, in the stage's
    /// order).
    pub fn start(
        cfg: &StreamOutputConfig,
        topologies: &[Topology],
        slots: Vec<Arc<LatestSlot<DeformedFrame>>>,
    ) -> io::Result<Self> {
        assert_eq!(
            topologies.len(),
            slots.len(),
            "a topology and a slot per actor"
        );
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
        let topo: Vec<Vec<u8>> = topologies
            .iter()
            .map(|t| {
                let mut b = Vec::new();
                encode_topology(t, &mut b);
                b
            })
            .collect();
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
                rt.block_on(serve(listeners, topo, slots, shutdown_rx, thread_stats));
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

/// What reading a request head gave.
enum HeadRead {
    /// The bytes up to its blank line (`end`) and whatever came with them.
    Head { bytes: Vec<u8>, end: usize },
    /// [`MAX_HEAD_BYTES`] without a blank line.
    TooLong,
    /// The peer closed, or the read failed, first.
    Closed,
}

/// Reads a request head from `sock`, at most [`MAX_HEAD_BYTES`].
async fn read_head(sock: &mut TcpStream) -> HeadRead {
    let mut buf = vec![0u8; MAX_HEAD_BYTES];
    let mut have = 0;
    while have < buf.len() {
        let n = match sock.read(&mut buf[have..]).await {
            Ok(0) | Err(_) => return HeadRead::Closed,
            Ok(n) => n,
        };
        // The blank line may straddle two reads: look from three bytes before.
        let from = have.saturating_sub(3);
        have += n;
        if let Some(end) = head_end(&buf[from..have]) {
            buf.truncate(have);
            return HeadRead::Head {
                bytes: buf,
                end: from + end,
            };
        }
    }
    HeadRead::TooLong
}

/// What a connection to the WebSocket port is: a client once its handshake is done, or
/// a page request, answered when `viewer` (else with a 404), or a bad one, answered
/// with a 400. The head must come within [`HEAD_TIMEOUT_SECS`]; the handshake or the
/// answer within `limit` more.
async fn handshake(sock: TcpStream, viewer: bool, limit: Duration) -> Accepted {
    let mut sock = sock;
    let head_limit = Duration::from_secs_f64(HEAD_TIMEOUT_SECS);
    let (bytes, end) = match tokio::time::timeout(head_limit, read_head(&mut sock)).await {
        Ok(HeadRead::Head { bytes, end }) => (bytes, end),
        Ok(HeadRead::TooLong) => (Vec::new(), 0),
        Ok(HeadRead::Closed) | Err(_) => return Accepted::Failed,
    };
    let rest = async move {
        let reply = match parse_head(&bytes[..end]) {
            _ if end == 0 => bad_request(&HeadError::TooLong),
            Ok(h) if h.websocket => {
                let rewind = Rewind {
                    prefix: bytes,
                    at: 0,
                    inner: sock,
                };
                let config = WebSocketConfig::default()
                    .max_message_size(Some(WS_MAX_MESSAGE_BYTES))
                    .max_frame_size(Some(WS_MAX_MESSAGE_BYTES));
                let ws = tokio_tungstenite::accept_async_with_config(rewind, Some(config))
                    .await
                    .ok()?;
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
    match tokio::time::timeout(limit, rest).await {
        Ok(Some(a)) => a,
        _ => Accepted::Failed,
    }
}

/// What a client sent that the server acts on.
enum Incoming {
    /// A ping (its pong is queued) or anything else: flush and go on.
    Flush,
    /// Its close (the reply is queued), or the connection is gone.
    Closed,
}

impl Conn {
    /// The next thing the client sends that needs an answer: a WebSocket client's
    /// messages are read (tungstenite queues the pong to a ping and the reply to a
    /// close); a TCP client is not read, and this never returns.
    async fn incoming(&mut self) -> Incoming {
        match self {
            Conn::Tcp(_) => std::future::pending().await,
            Conn::Ws(w) => match w.next().await {
                Some(Ok(WsMessage::Close(_))) | Some(Err(_)) | None => Incoming::Closed,
                Some(Ok(_)) => Incoming::Flush,
            },
        }
    }

    /// Sends what tungstenite has queued (a pong, a close reply); false on error or
    /// timeout.
    async fn flush(&mut self) -> bool {
        let limit = Duration::from_secs_f64(GOODBYE_TIMEOUT_SECS);
        match self {
            Conn::Tcp(_) => true,
            Conn::Ws(w) => matches!(tokio::time::timeout(limit, w.flush()).await, Ok(Ok(()))),
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

/// The accept loop's connections: clients served, refusals under way and WebSocket-port
/// connections in their handshake (with their abort handles, oldest first).
struct Connections {
    clients: JoinSet<()>,
    refusals: JoinSet<()>,
    handshakes: JoinSet<Accepted>,
    /// The handshakes under way, oldest first, with when each began.
    handshake_order: std::collections::VecDeque<(tokio::task::AbortHandle, tokio::time::Instant)>,
    max_clients: usize,
    viewer: bool,
    /// The goodbye of a connection the server has no room for.
    full: Arc<Vec<u8>>,
    /// Each actor's topology message.
    topo: Arc<Vec<Vec<u8>>>,
    frames: FrameRx,
    shutdown: ShutdownRx,
    stats: Arc<StreamStats>,
}

impl Connections {
    /// `None` while there is room for a handshake; else when the oldest will have had
    /// its grace (the WebSocket port is not accepted from until then).
    fn handshakes_full_until(&mut self) -> Option<tokio::time::Instant> {
        self.handshake_order.retain(|(h, _)| !h.is_finished());
        if self.handshake_order.len() < MAX_HANDSHAKES {
            return None;
        }
        let grace = Duration::from_secs_f64(HANDSHAKE_GRACE_SECS);
        self.handshake_order
            .front()
            .map(|(_, began)| *began + grace)
    }

    /// A connection to the WebSocket port: into the handshake budget, the oldest
    /// handshake cut when it is spent (the loop waits out its grace first).
    fn handshake(&mut self, sock: TcpStream) {
        if self.handshakes_full_until().is_some() {
            if let Some((oldest, _)) = self.handshake_order.pop_front() {
                oldest.abort();
            }
        }
        let limit = Duration::from_secs_f64(WRITE_TIMEOUT_SECS);
        let viewer = self.viewer;
        let handle = self.handshakes.spawn(handshake(sock, viewer, limit));
        self.handshake_order
            .push_back((handle, tokio::time::Instant::now()));
    }

    /// A handshake's end: a client (served, or refused when the server is full), a page
    /// answered, or a failure (cut included).
    fn handshake_done(&mut self, done: Result<Accepted, tokio::task::JoinError>) {
        match done {
            Ok(Accepted::Client(conn)) => self.admit(conn),
            Ok(Accepted::Page) => {
                self.stats.pages_served.fetch_add(1, Ordering::Relaxed);
            }
            Ok(Accepted::Failed) | Err(_) => {
                self.stats.handshake_errors.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// Serves `conn`, or refuses it when `max_clients` are served.
    fn admit(&mut self, conn: Conn) {
        while self.clients.try_join_next().is_some() {}
        if self.clients.len() >= self.max_clients {
            self.stats.refused.fetch_add(1, Ordering::Relaxed);
            tracing::debug!("vertex stream: refused, full");
            if self.refusals.len() < MAX_REFUSALS {
                self.refusals.spawn(refuse(conn, Arc::clone(&self.full)));
            }
            return;
        }
        self.stats.connections.fetch_add(1, Ordering::Relaxed);
        tracing::debug!("vertex stream: client connected");
        self.clients.spawn(serve_client(
            conn,
            Arc::clone(&self.topo),
            self.frames.clone(),
            self.shutdown.clone(),
            Arc::clone(&self.stats),
        ));
    }
}

async fn serve(
    listeners: Listeners,
    topo: Arc<Vec<Vec<u8>>>,
    slots: Vec<Arc<LatestSlot<DeformedFrame>>>,
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
    let max_clients = listeners.max_clients;
    let (tcp, ws) = (register(listeners.tcp), register(listeners.ws));
    let (frames_tx, frames_rx) = watch::channel(vec![None; slots.len()]);
    let frames_tx = Arc::new(frames_tx);
    let mut dispatchers = JoinSet::new();
    for (actor, slot) in slots.into_iter().enumerate() {
        let tx = Arc::clone(&frames_tx);
        dispatchers.spawn(dispatch(slot, actor, tx, shutdown.clone()));
    }
    // The dispatchers hold the sender: when they have all ended, the clients see it.
    drop(frames_tx);
    let mut full = Vec::new();
    encode_goodbye(
        &format!("server full: {max_clients} clients connected (its max_clients)"),
        &mut full,
    );
    let mut c = Connections {
        clients: JoinSet::new(),
        refusals: JoinSet::new(),
        handshakes: JoinSet::new(),
        handshake_order: std::collections::VecDeque::new(),
        max_clients,
        viewer: listeners.viewer,
        full: Arc::new(full),
        topo,
        frames: frames_rx,
        shutdown: shutdown.clone(),
        stats: Arc::clone(&stats),
    };
    let (mut backoff, mut report) = (
        AcceptBackoff::default(),
        Throttle::new(ACCEPT_REPORT_INTERVAL_S),
    );
    let started = tokio::time::Instant::now();
    let mut paused_until: Option<tokio::time::Instant> = None;
    loop {
        let full_until = c.handshakes_full_until();
        let ws_room = full_until.is_none_or(|t| t <= tokio::time::Instant::now());
        let (r, websocket) = tokio::select! {
            r = accept_on(&tcp), if paused_until.is_none() => (r, false),
            r = accept_on(&ws), if paused_until.is_none() && ws_room => (r, true),
            _ = tokio::time::sleep_until(full_until.unwrap_or(started)), if !ws_room => continue,
            _ = tokio::time::sleep_until(paused_until.unwrap_or(started)), if paused_until.is_some() => {
                paused_until = None;
                continue;
            }
            _ = shutdown.changed() => break,
            Some(_) = c.clients.join_next(), if !c.clients.is_empty() => continue,
            Some(_) = c.refusals.join_next(), if !c.refusals.is_empty() => continue,
            Some(done) = c.handshakes.join_next(), if !c.handshakes.is_empty() => {
                c.handshake_done(done);
                continue;
            }
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
        tracing::debug!(%peer, websocket, "vertex stream: connection");
        if let Err(e) = sock.set_nodelay(true) {
            tracing::debug!("TCP_NODELAY not set on a stream connection: {e}");
        }
        if websocket {
            c.handshake(sock);
        } else {
            c.admit(Conn::Tcp(sock));
        }
    }
    let Connections {
        mut clients,
        refusals,
        handshakes,
        ..
    } = c;
    drop((tcp, ws, refusals, handshakes));
    while let Some(r) = dispatchers.join_next().await {
        if let Err(e) = r {
            tracing::error!("a stream frame dispatcher failed: {e}");
        }
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

/// Encodes each frame published to `slot` (actor `actor`'s) once and hands the bytes to
/// every client, until shutdown.
async fn dispatch(
    slot: Arc<LatestSlot<DeformedFrame>>,
    actor: usize,
    frames_tx: Arc<watch::Sender<Newest>>,
    mut shutdown: ShutdownRx,
) {
    loop {
        tokio::select! {
            f = slot.next() => {
                let mut bytes = Vec::with_capacity(64 + 12 * f.vertices_m.len());
                encode_frame(&f.wire(), &mut bytes);
                let e = Encoded { frame: f.frame, bytes };
                drop(f);
                let e = Arc::new(e);
                frames_tx.send_modify(|newest| newest[actor] = Some(e));
            }
            _ = shutdown.changed() => break,
        }
    }
}

/// Sends a client the server had no room for the `goodbye` and closes it; each step
/// bounded by [`GOODBYE_TIMEOUT_SECS`].
async fn refuse(mut conn: Conn, goodbye: Arc<Vec<u8>>) {
    if conn.send(&goodbye, GOODBYE_TIMEOUT_SECS).await {
        conn.close().await;
    }
}

async fn serve_client(
    mut conn: Conn,
    topo: Arc<Vec<Vec<u8>>>,
    mut frames: FrameRx,
    mut shutdown: ShutdownRx,
    stats: Arc<StreamStats>,
) {
    stats.clients.fetch_add(1, Ordering::Relaxed);
    let mut ok = true;
    for t in topo.iter() {
        ok = ok && conn.send(t, WRITE_TIMEOUT_SECS).await;
    }
    // Send the newest frames at once rather than waiting for the next.
    frames.mark_changed();
    let mut buf = Vec::new();
    // Each actor's last frame sent, and the newest ones to send.
    let mut last: Vec<Option<u64>> = vec![None; topo.len()];
    let mut newest: Newest = Vec::with_capacity(topo.len());
    // The client closed (its close answered) or hung up: no goodbye, and no error.
    let mut gone = false;
    while ok {
        tokio::select! {
            biased;
            _ = shutdown.changed() => break,
            m = conn.incoming() => match m {
                Incoming::Flush => ok = conn.flush().await,
                Incoming::Closed => {
                    gone = true;
                    // The close reply, when the client sent a close (an error when it
                    // hung up: nothing is owed then).
                    if !conn.flush().await {
                        tracing::debug!("a stream client went without a clean close");
                    }
                    break;
                }
            },
            r = frames.changed() => {
                if r.is_err() {
                    // The dispatcher has gone: the server is shutting down. Wait for
                    // its reason (an error means the server itself has gone, which ends
                    // the client all the same); the guard it returns is let go at once.
                    drop(shutdown.wait_for(Option::is_some).await);
                    break;
                }
                newest.clear();
                newest.extend(frames.borrow_and_update().iter().cloned());
                for (f, last) in newest.iter().zip(&mut last) {
                    let Some(f) = f else { continue };
                    match *last {
                        Some(l) if l >= f.frame => continue,
                        Some(l) => {
                            stats.frames_skipped.fetch_add(f.frame - l - 1, Ordering::Relaxed);
                        }
                        None => {}
                    }
                    *last = Some(f.frame);
                    ok = conn.send(&f.bytes, WRITE_TIMEOUT_SECS).await;
                    if !ok {
                        break;
                    }
                    stats.frames_sent.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
    if ok && !gone {
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
