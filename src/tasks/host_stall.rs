//! A flight thread's own late wake-up, read as the host's stall.
//!
//! The watchdog (the flight's highest priority, a check every 0.5 ms) and the ESC writer
//! (every `esc.resend_ms`, and at each command): when one of them wakes more than
//! [`OWN_STALL_US`] after it was due, the host most likely stalled every flight thread with it
//! (a virtual machine's pause, a kernel's hiccup). The IMU's frames sent meanwhile wait in the
//! port's buffer and the control path resumes with them, so judging that time as a silent
//! IMU, a late command or a stale one would halt a vehicle that has already flown through the
//! pause. A late wake-up may also be load, a slow bus or a hung path's: so the time excused
//! is budgeted, [`BUDGET_US`] of credit refilled at that much a second (a single pause of up
//! to about 330 ms is excused whole, as the credit refills while it lasts). Over any time T at
//! most `BUDGET_US` (1 + T / 1 s) is left out: with the default 12 ms IMU timeout a rule trips
//! within about 0.35 s of a host that stalls without end, and at once on a healthy one.

/// A wake-up later than this is the host's stall, not jitter, µs.
pub const OWN_STALL_US: i64 = 5_000;

/// Of an excused stall, this much still counts as judged time, µs: the rules' limits keep
/// their margin over a pause that began just before a frame was due.
pub const COUNTED_US: i64 = 1_000;

/// The credit of excusable time, and its refill per second, µs. A stall longer than what is
/// left (refilled over the stall itself) is judged whole.
pub const BUDGET_US: i64 = 250_000;

/// One thread's budget of excusable time.
#[derive(Debug, Default, Clone, Copy)]
pub struct StallWatch {
    credit_us: i64,
    /// When the credit was last refilled; `None`: full.
    updated_us: Option<i64>,
}

impl StallWatch {
    /// A wake-up at `now_us` that was due `late_us` earlier: the span the rules leave out, if
    /// this wake-up ends a stall the budget still covers.
    pub fn excused(&mut self, late_us: i64, now_us: i64) -> Option<(i64, i64)> {
        self.credit_us = match self.updated_us {
            None => BUDGET_US,
            Some(t_us) => {
                let refill_us = (now_us - t_us).max(0).saturating_mul(BUDGET_US) / 1_000_000;
                self.credit_us.saturating_add(refill_us).min(BUDGET_US)
            }
        };
        self.updated_us = Some(now_us);
        if !Self::is_stall(late_us) {
            return None;
        }
        let span = (now_us - late_us + COUNTED_US, now_us);
        let len_us = span.1 - span.0;
        if len_us > self.credit_us {
            return None;
        }
        self.credit_us -= len_us;
        Some(span)
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
    fn stalls_are_excused_within_a_budget_refilled_each_second() {
        let mut w = StallWatch::default();
        assert_eq!(w.excused(300, 10_000), None, "jitter");
        assert_eq!(
            w.excused(200_000, 300_000),
            Some((101_000, 300_000)),
            "a pause, all but its first millisecond"
        );
        // 51 ms left: a short stall is excused, a long one judged whole.
        assert_eq!(w.excused(20_000, 320_000), Some((301_000, 320_000)));
        assert_eq!(w.excused(100_000, 420_000), None);
        // 62 ms left after that refusal, refilled at 250 ms a second: 0.3 s later, 137 ms. A
        // span of the credit passes, one a microsecond over it is judged whole.
        let mut edge = w;
        assert_eq!(edge.excused(138_000, 720_000), Some((583_000, 720_000)));
        assert_eq!(w.excused(138_001, 720_000), None);
        // Stalls without end: at most the budget plus its refill is ever excused.
        let (mut w, mut excused_us) = (StallWatch::default(), 0);
        let mut t_us = 0;
        for _ in 0..1000 {
            t_us += 100_000;
            if let Some((a, b)) = w.excused(99_500, t_us) {
                excused_us += b - a;
            }
            t_us += 500;
            assert_eq!(w.excused(0, t_us), None);
        }
        let bound_us = BUDGET_US + BUDGET_US * t_us / 1_000_000;
        assert!(excused_us <= bound_us, "{excused_us} > {bound_us}");
        assert!(excused_us > bound_us / 2, "{excused_us}");
    }
}
