//! The vertex stream server, over TCP and over WebSocket (each on its own port): each
//! client gets the topology, then every solved frame in the format of
//! `protocols/vertex-stream.md`, and a goodbye at shutdown. Over WebSocket every message
//! is one binary WebSocket message holding exactly the same bytes.
//!
//! Runs on its own thread with a single-threaded tokio runtime. The solver publishes into
//! a [`LatestSlot`]; a dispatcher task encodes each frame once and puts the bytes into a
//! `watch` channel that every client task follows, so a slow client skips to the newest frame (the skipped frames
//! are counted) and never holds up the loop or the other clients.

use super::frame::DeformedFrame;
use crate::protocol::vertex_stream::{encode_frame, encode_goodbye, encode_topology, Topology};
use crate::runtime::slot::LatestSlot;
use futures_util::SinkExt;
use std::io;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinSet;
use tokio_tungstenite::tungstenite::Message as WsMessage;
use tokio_tungstenite::WebSocketStream;

/// A client whose socket accepts nothing for this long is disconnected, seconds.
pub const WRITE_TIMEOUT_SECS: f64 = 5.0;
/// How long shutdown waits for clients to take their goodbye, seconds.
const GOODBYE_TIMEOUT_SECS: f64 = 1.0;

/// What the server has done (monotonic except `clients`).
#[derive(Debug, Default)]
pub struct StreamStats {
    /// Clients connected now.
    pub clients: AtomicU64,
    /// Connections accepted in all.
    pub connections: AtomicU64,
    /// Frame messages written, over all clients.
    pub frames_sent: AtomicU64,
    /// Frames a client skipped because it was slower than the loop, over all clients.
    pub frames_skipped: AtomicU64,
    /// Clients dropped on a write error or timeout (a client that hangs up is noticed
    /// at the next write, so it counts here too).
    pub write_errors: AtomicU64,
    /// WebSocket connections whose handshake failed or timed out.
    pub handshake_errors: AtomicU64,
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
    /// Binds `tcp` and `ws` (either may be `None`; port 0 picks a free port) and serves
    /// frames published to `slot`.
    pub fn start(
        tcp: Option<SocketAddr>,
        ws: Option<SocketAddr>,
        topology: &Topology,
        slot: Arc<LatestSlot<DeformedFrame>>,
    ) -> io::Result<Self> {
        let bind = |a: Option<SocketAddr>| -> io::Result<Option<std::net::TcpListener>> {
            a.map(|a| {
                let l = std::net::TcpListener::bind(a)?;
                l.set_nonblocking(true)?;
                Ok(l)
            })
            .transpose()
        };
        let (tcp_l, ws_l) = (bind(tcp)?, bind(ws)?);
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
                rt.block_on(serve(tcp_l, ws_l, topo, slot, shutdown_rx, thread_stats));
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
            // The thread ends within GOODBYE_TIMEOUT_SECS; a panic there was already
            // reported by the panic hook.
            let _ = t.join();
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
    Ws(Box<WebSocketStream<TcpStream>>),
}

impl Conn {
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
        let _ = match self {
            Conn::Tcp(s) => tokio::time::timeout(limit, s.shutdown()).await.map(|_| ()),
            // The WebSocket close handshake (the stream's own `close`, not `SinkExt::close`).
            Conn::Ws(w) => tokio::time::timeout(limit, WebSocketStream::close(&mut **w, None))
                .await
                .map(|_| ()),
        };
    }
}

async fn accept_on(l: &Option<TcpListener>) -> io::Result<(TcpStream, SocketAddr)> {
    match l {
        Some(l) => l.accept().await,
        None => std::future::pending().await,
    }
}

async fn serve(
    tcp: Option<std::net::TcpListener>,
    ws: Option<std::net::TcpListener>,
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
    let (tcp, ws) = (register(tcp), register(ws));
    let (frames_tx, frames_rx) = watch::channel(None);
    let mut dispatch_shutdown = shutdown.clone();
    let dispatcher = tokio::spawn(async move {
        loop {
            tokio::select! {
                f = slot.next() => {
                    let mut bytes = Vec::with_capacity(64 + 12 * f.vertices_m.len());
                    encode_frame(&f.wire(), &mut bytes);
                    let e = Encoded { frame: f.frame, bytes };
                    drop(f);
                    frames_tx.send_replace(Some(Arc::new(e)));
                }
                _ = dispatch_shutdown.changed() => break,
            }
        }
    });
    let mut clients = JoinSet::new();
    loop {
        let (r, websocket) = tokio::select! {
            r = accept_on(&tcp) => (r, false),
            r = accept_on(&ws) => (r, true),
            _ = shutdown.changed() => break,
            Some(_) = clients.join_next(), if !clients.is_empty() => continue,
        };
        match r {
            Ok((sock, peer)) => {
                stats.connections.fetch_add(1, Ordering::Relaxed);
                tracing::debug!(%peer, websocket, "vertex stream: client connected");
                let (topo, frames, shutdown, stats) = (
                    Arc::clone(&topo),
                    frames_rx.clone(),
                    shutdown.clone(),
                    Arc::clone(&stats),
                );
                clients.spawn(async move {
                    let _ = sock.set_nodelay(true);
                    let conn = if websocket {
                        let hs = tokio::time::timeout(
                            Duration::from_secs_f64(WRITE_TIMEOUT_SECS),
                            tokio_tungstenite::accept_async(sock),
                        )
                        .await;
                        match hs {
                            Ok(Ok(w)) => Conn::Ws(Box::new(w)),
                            _ => {
                                stats.handshake_errors.fetch_add(1, Ordering::Relaxed);
                                return;
                            }
                        }
                    } else {
                        Conn::Tcp(sock)
                    };
                    serve_client(conn, topo, frames, shutdown, stats).await;
                });
            }
            Err(e) => tracing::warn!(error = %e, "vertex stream: accept failed"),
        }
    }
    drop((tcp, ws));
    let _ = dispatcher.await;
    let _ = tokio::time::timeout(Duration::from_secs_f64(GOODBYE_TIMEOUT_SECS * 2.0), async {
        while clients.join_next().await.is_some() {}
    })
    .await;
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
                    // The dispatcher has gone: the server is shutting down.
                    let _ = shutdown.wait_for(Option::is_some).await;
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
        let _ = conn.send(&buf, GOODBYE_TIMEOUT_SECS).await;
        conn.close().await;
    } else {
        stats.write_errors.fetch_add(1, Ordering::Relaxed);
    }
    stats.clients.fetch_sub(1, Ordering::Relaxed);
}
