//! Ground floor: what every layer uses at run time. The clock (system or manual, time
//! passed in so tests drive it), the latest-value slots between threads, and the socket
//! waits of the network inputs and senders.

pub mod clock;
pub mod net;
pub mod slot;
