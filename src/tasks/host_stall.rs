//! A flight thread's own late wake-up, read as the host's stall.
//!
//! The watchdog and the ESC writer run at SCHED_FIFO priorities above every other flight
//! thread: when one of them wakes more than [`OWN_STALL_US`] after it was due, the host
//! stalled every flight thread with it (a virtual machine's pause, a kernel's hiccup). The
//! IMU's frames sent meanwhile wait in the port's buffer and the control path resumes with
//! them, so judging that time as a silent IMU, a late command or a stale one would halt a
//! vehicle that has already flown through the pause. Only an isolated stall is excused, and
//! only on a thread that holds its FIFO priority (else a late wake-up is mere load): a host
//! that stalls again and again, or a thread starved by load, is judged on the wall clock.

/// A wake-up later than this is the host's stall, not jitter, µs.
pub const OWN_STALL_US: i64 = 5_000;

/// Of an excused stall, this much still counts as judged time, µs: the rules' limits keep
/// their margin over a pause that began just before a frame was due.
pub const COUNTED_US: i64 = 1_000;

/// One thread's record of its wake-ups.
#[derive(Debug, Default, Clone, Copy)]
pub struct StallWatch {
    stalled_before: bool,
}

impl StallWatch {
    /// A wake-up at `now_us` that was due `late_us` earlier, on a thread at its FIFO priority
    /// or not (`fifo`): the span the rules leave out, if this wake-up ends an isolated stall.
    pub fn excused(&mut self, late_us: i64, now_us: i64, fifo: bool) -> Option<(i64, i64)> {
        let stalled = late_us > OWN_STALL_US;
        let isolated = stalled && !self.stalled_before;
        self.stalled_before = stalled;
        (isolated && fifo).then_some((now_us - late_us + COUNTED_US, now_us))
    }

    /// The wake-up was late by more than [`OWN_STALL_US`].
    pub fn is_stall(late_us: i64) -> bool {
        late_us > OWN_STALL_US
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_an_isolated_stall_on_a_fifo_thread_is_excused() {
        let mut w = StallWatch::default();
        assert_eq!(w.excused(300, 10_000, true), None, "jitter");
        assert_eq!(
            w.excused(100_000, 200_000, true),
            Some((101_000, 200_000)),
            "a pause: all but its first millisecond"
        );
        assert_eq!(w.excused(100_000, 300_000, true), None, "and again at once");
        assert_eq!(w.excused(200, 300_500, true), None);
        assert_eq!(w.excused(100_000, 400_500, false), None, "no FIFO: load");
        assert_eq!(w.excused(200, 401_000, true), None);
        assert!(w.excused(100_000, 501_000, true).is_some());
    }
}
