//! Socket helpers shared by the network inputs and the replay senders.

/// Whether a socket error only means "nothing yet" (a read timeout, a non-blocking socket
/// with nothing to read, or an interruption), not a failure.
pub fn is_wait(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::WouldBlock
            | std::io::ErrorKind::TimedOut
            | std::io::ErrorKind::Interrupted
    )
}
