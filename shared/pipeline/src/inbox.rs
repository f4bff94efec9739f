//! Puts received frames back in sequence order, drops duplicates (a restarted publisher
//! replays its history) and notices frames that never come.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use supermvo_messages::FrameHeader;

/// Frames received and not yet taken, in sequence order.
#[derive(Debug)]
pub struct Inbox<T> {
    items: BTreeMap<u64, (FrameHeader, T, u64)>,
    next: u64,
    stride: u64,
    /// Since when a later frame is waiting for a missing `next`.
    blocked_since: Option<Instant>,
}

impl<T> Inbox<T> {
    /// An inbox expecting `next`, then every `stride`-th sequence number after it.
    pub fn new(next: u64, stride: u64) -> Self {
        Self {
            items: BTreeMap::new(),
            next,
            stride: stride.max(1),
            blocked_since: None,
        }
    }

    /// The next sequence number expected.
    pub fn next(&self) -> u64 {
        self.next
    }

    /// Frames waiting.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// Whether nothing is waiting.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Keeps a received frame (received at `t_ns`) unless it is already past or not ours.
    pub fn insert(&mut self, h: FrameHeader, item: T, t_ns: u64) {
        if h.seq < self.next || (h.seq - self.next) % self.stride != 0 {
            return;
        }
        self.items.entry(h.seq).or_insert((h, item, t_ns));
    }

    /// Whether the next frame is here.
    pub fn ready(&self) -> bool {
        self.items.contains_key(&self.next)
    }

    /// The next frame if present.
    pub fn peek(&self) -> Option<&(FrameHeader, T, u64)> {
        self.items.get(&self.next)
    }

    /// Takes the next frame and advances.
    pub fn pop(&mut self) -> Option<(FrameHeader, T, u64)> {
        let item = self.items.remove(&self.next)?;
        self.next += self.stride;
        self.blocked_since = None;
        Some(item)
    }

    /// Whether the next frame has been missing for longer than `timeout` while later ones
    /// are here: then it is lost, and [`Inbox::skip`] moves past it.
    pub fn gap_expired(&mut self, timeout: Duration) -> bool {
        if self.ready() || self.items.is_empty() {
            self.blocked_since = None;
            return false;
        }
        let since = *self.blocked_since.get_or_insert_with(Instant::now);
        since.elapsed() >= timeout
    }

    /// Gives up on the next frame.
    pub fn skip(&mut self) -> u64 {
        let s = self.next;
        self.next += self.stride;
        self.blocked_since = None;
        s
    }

    /// Forgets everything before `seq` and expects `seq` next.
    pub fn reset_to(&mut self, seq: u64) {
        self.next = seq;
        self.items = self.items.split_off(&seq);
        self.blocked_since = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use supermvo_messages::Status;

    fn h(seq: u64) -> FrameHeader {
        FrameHeader::new(seq, seq, 0.0, Status::Ok)
    }

    #[test]
    fn reorders_and_drops_duplicates() {
        let mut b = Inbox::new(0, 1);
        b.insert(h(1), "b", 0);
        assert!(!b.ready());
        b.insert(h(0), "a", 0);
        b.insert(h(0), "dup", 0);
        assert_eq!(b.pop().unwrap().1, "a");
        assert_eq!(b.pop().unwrap().1, "b");
        b.insert(h(1), "late duplicate", 0);
        assert!(b.is_empty());
    }

    #[test]
    fn strides_for_workers() {
        let mut b = Inbox::new(1, 2);
        for s in 0..6 {
            b.insert(h(s), s, 0);
        }
        assert_eq!(b.len(), 3);
        assert_eq!(b.pop().unwrap().1, 1);
        assert_eq!(b.pop().unwrap().1, 3);
    }

    #[test]
    fn a_missing_frame_expires_only_when_later_ones_wait() {
        let mut b = Inbox::new(0, 1);
        assert!(!b.gap_expired(Duration::ZERO));
        b.insert(h(1), (), 0);
        assert!(b.gap_expired(Duration::ZERO));
        assert!(!b.gap_expired(Duration::from_secs(60)));
        assert_eq!(b.skip(), 0);
        assert!(b.ready());
    }
}
