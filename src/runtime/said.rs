//! How often code that meets the network says something: each kind of problem once
//! ([`SaidOnce`]), and a failure that repeats fast at most once per interval, with the
//! count of the occurrences not said ([`Throttle`]). Per-packet events stay counters;
//! these only decide when a line is worth writing. Time is passed in.

/// Most kinds of problem a [`SaidOnce`] remembers; beyond them nothing new is said (the
/// counters in the closing summary still carry every occurrence).
pub const MAX_KINDS: usize = 32;

/// The kinds of problem already said.
#[derive(Debug)]
pub struct SaidOnce<K> {
    said: Vec<K>,
}

impl<K: PartialEq> Default for SaidOnce<K> {
    fn default() -> Self {
        Self { said: Vec::new() }
    }
}

impl<K: PartialEq> SaidOnce<K> {
    /// True the first time `kind` comes (the caller says it then), false after, and
    /// false for every kind once [`MAX_KINDS`] were said.
    pub fn first(&mut self, kind: K) -> bool {
        if self.said.len() >= MAX_KINDS || self.said.contains(&kind) {
            return false;
        }
        self.said.push(kind);
        true
    }
}

/// At most one line per `interval_s` about a failure that may repeat thousands of times
/// a second.
#[derive(Clone, Debug)]
pub struct Throttle {
    interval_s: f64,
    last_s: f64,
    unsaid: u64,
}

impl Throttle {
    pub fn new(interval_s: f64) -> Self {
        Self {
            interval_s,
            last_s: f64::NEG_INFINITY,
            unsaid: 0,
        }
    }

    /// Takes one occurrence at `now_s` (seconds on any monotonic clock): `Some(n)` when
    /// a line is due, `n` being the occurrences since the last line that were not said;
    /// `None` when this one is only counted.
    pub fn hit(&mut self, now_s: f64) -> Option<u64> {
        if now_s - self.last_s >= self.interval_s {
            self.last_s = now_s;
            Some(std::mem::take(&mut self.unsaid))
        } else {
            self.unsaid += 1;
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_kind_is_said_once_and_the_kinds_are_bounded() {
        let mut s = SaidOnce::default();
        assert!(s.first("length"));
        assert!(!s.first("length"));
        assert!(s.first("cookie"));
        for k in 0..100 {
            s.first(k.to_string().leak() as &str);
        }
        assert!(!s.first("new after the bound"));
    }

    #[test]
    fn a_fast_failure_is_said_once_a_second_with_the_rest_counted() {
        let mut t = Throttle::new(1.0);
        assert_eq!(t.hit(10.0), Some(0));
        // 10 000 more in the next 0.99 s: counted, not said.
        let said = (1..=10_000)
            .filter(|k| t.hit(10.0 + *k as f64 * 0.99e-4).is_some())
            .count();
        assert_eq!(said, 0);
        assert_eq!(t.hit(11.0), Some(10_000));
        assert_eq!(t.hit(11.5), None);
        assert_eq!(t.hit(12.5), Some(1));
    }
}
