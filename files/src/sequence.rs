//! Accounting of frame sequence numbers: proves a recording has no gap (or counts the gap).

/// Tracks the `frame_seq` of every received frame.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SequenceTracker {
    first: Option<u64>,
    last: Option<u64>,
    received: u64,
    /// Frames skipped by forward jumps (including frames before the first one received).
    missing: u64,
    /// Frames that arrived with a sequence number not greater than the previous one.
    out_of_order: u64,
}

impl SequenceTracker {
    pub fn new() -> Self {
        Self::default()
    }

    /// Registers a frame; returns how many frames are missing right before it (0 normally).
    pub fn observe(&mut self, seq: u64) -> u64 {
        self.received += 1;
        let gap = match self.last {
            None => seq, // a run's frames start at 0
            Some(last) if seq > last => seq - last - 1,
            Some(_) => {
                self.out_of_order += 1;
                return 0;
            }
        };
        self.first.get_or_insert(seq);
        self.last = Some(seq);
        self.missing += gap;
        gap
    }

    pub fn received(&self) -> u64 {
        self.received
    }
    pub fn missing(&self) -> u64 {
        self.missing
    }
    pub fn out_of_order(&self) -> u64 {
        self.out_of_order
    }
    pub fn first(&self) -> Option<u64> {
        self.first
    }
    pub fn last(&self) -> Option<u64> {
        self.last
    }

    /// True if every frame 0..=last arrived exactly once.
    pub fn is_complete(&self) -> bool {
        self.missing == 0 && self.out_of_order == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contiguous_frames_are_complete() {
        let mut t = SequenceTracker::new();
        for s in 0..5 {
            assert_eq!(t.observe(s), 0);
        }
        assert!(t.is_complete());
        assert_eq!((t.received(), t.last()), (5, Some(4)));
    }

    #[test]
    fn gaps_late_start_and_repeats_are_counted() {
        let mut t = SequenceTracker::new();
        assert_eq!(t.observe(2), 2); // frames 0 and 1 never came
        assert_eq!(t.observe(5), 2);
        assert_eq!(t.observe(5), 0);
        assert_eq!((t.missing(), t.out_of_order()), (4, 1));
        assert!(!t.is_complete());
    }
}
