//! Pure codecs: bytes in, typed messages out (and back), no sockets, no threads, no
//! clocks. Each wire format is specified in `protocols/`.

pub mod glove;
pub mod natnet;
pub mod osc;
pub mod pc2;
pub mod url;
pub mod vertex_stream;
pub mod vrpn;
