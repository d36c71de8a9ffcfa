//! The frame → ESC write latency and its stages, recorded without locks.
//!
//! Four instants stamp each flight command: the frame's decode (when its bytes were read), the
//! estimate (the Kalman step done), the command (the control law done) and the bus write. The
//! ESC writer records the whole path and its three stages into histograms of 1 µs buckets made
//! of atomics: the writer never waits on a reader (the console's statistics line, the report),
//! and nothing is allocated while flying. Percentiles are exact to the microsecond below
//! `BUCKETS` µs; past it a percentile reads as the maximum, which is always exact.

use serde::Serialize;
use std::sync::atomic::{AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::time::Instant;

/// 1 µs buckets: 10 ms, the whole control period.
const BUCKETS: usize = 10_000;
/// Samples kept for the console's last-second view (100 Hz).
const RECENT: usize = 128;

/// p50, p99 and max of a latency, µs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Percentiles {
    pub p50: u32,
    pub p99: u32,
    pub max: u32,
}

/// The stages of the frame → ESC write path, µs each.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct StageFigures {
    /// Frame read and decoded → the estimate (hand-off to the estimator, the Kalman step).
    pub decode_to_estimate: Percentiles,
    /// The estimate → the motor command (hand-off to the controller, the control law).
    pub estimate_to_command: Percentiles,
    /// The command → its bus write acknowledged (hand-off to the ESC writer, the I2C write).
    pub command_to_write: Percentiles,
}

/// The whole path and its stages.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct LatencyFigures {
    pub total: Percentiles,
    pub stages: StageFigures,
}

/// When a command's frame was decoded, its estimate made and the command given.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stamps {
    pub decoded: Instant,
    pub estimated: Instant,
    pub commanded: Instant,
}

/// One latency's histogram, maximum and newest samples; every field an atomic.
pub struct Histogram {
    counts: Box<[AtomicU32]>,
    overflow: AtomicU64,
    max_us: AtomicU32,
    recent: [AtomicU32; RECENT],
    next: AtomicUsize,
}

impl Default for Histogram {
    fn default() -> Self {
        Histogram {
            counts: (0..BUCKETS).map(|_| AtomicU32::new(0)).collect(),
            overflow: AtomicU64::new(0),
            max_us: AtomicU32::new(0),
            recent: std::array::from_fn(|_| AtomicU32::new(0)),
            next: AtomicUsize::new(0),
        }
    }
}

impl Histogram {
    pub fn record(&self, us: u32) {
        if let Some(c) = self.counts.get(us as usize) {
            c.fetch_add(1, Ordering::Relaxed);
        } else {
            self.overflow.fetch_add(1, Ordering::Relaxed);
        }
        self.max_us.fetch_max(us, Ordering::Relaxed);
        let k = self.next.load(Ordering::Relaxed);
        self.recent[k % RECENT].store(us, Ordering::Relaxed);
        self.next.store(k + 1, Ordering::Release);
    }

    /// Samples recorded.
    pub fn count(&self) -> u64 {
        let below: u64 = self
            .counts
            .iter()
            .map(|c| u64::from(c.load(Ordering::Relaxed)))
            .sum();
        below + self.overflow.load(Ordering::Relaxed)
    }

    /// The value at rank round((n − 1)·q) of the sorted samples, as the report always took it.
    pub fn percentiles(&self) -> Percentiles {
        let n = self.count();
        let max = self.max_us.load(Ordering::Relaxed);
        let at = |q: f64| -> u32 {
            if n == 0 {
                return 0;
            }
            let rank = ((n - 1) as f64 * q).round() as u64;
            let mut seen = 0u64;
            for (us, c) in self.counts.iter().enumerate() {
                seen += u64::from(c.load(Ordering::Relaxed));
                if seen > rank {
                    return us as u32;
                }
            }
            max
        };
        Percentiles {
            p50: at(0.5),
            p99: at(0.99),
            max,
        }
    }

    /// The median and the maximum of the newest `n` samples (≤ 128); 0 without samples.
    pub fn recent_median_max(&self, n: usize) -> (u32, u32) {
        let mut v = [0u32; RECENT];
        let mut len = 0;
        for (slot, s) in v.iter_mut().zip(self.recent(n)) {
            *slot = s;
            len += 1;
        }
        let v = &mut v[..len];
        v.sort_unstable();
        (
            v.get(len / 2).copied().unwrap_or(0),
            v.last().copied().unwrap_or(0),
        )
    }

    /// The newest samples, at most `n` (≤ 128), newest first.
    pub fn recent(&self, n: usize) -> impl Iterator<Item = u32> + '_ {
        let end = self.next.load(Ordering::Acquire);
        let n = n.min(RECENT).min(end);
        (end - n..end)
            .rev()
            .map(|k| self.recent[k % RECENT].load(Ordering::Relaxed))
    }
}

/// The whole path's histogram and one per stage.
#[derive(Default)]
pub struct LatencyLog {
    pub total: Histogram,
    /// decode → estimate, estimate → command, command → write.
    pub stages: [Histogram; 3],
}

/// Microseconds from `a` to `b`, 0 if `b` is not later, saturating at u32::MAX.
fn us_between(a: Instant, b: Instant) -> u32 {
    b.saturating_duration_since(a)
        .as_micros()
        .min(u128::from(u32::MAX)) as u32
}

impl std::fmt::Debug for LatencyLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LatencyLog")
            .field("figures", &self.figures())
            .finish()
    }
}

impl LatencyLog {
    /// A command with these stamps was written at `written`.
    pub fn record(&self, s: &Stamps, written: Instant) {
        self.total.record(us_between(s.decoded, written));
        let [estimate, command, write] = &self.stages;
        estimate.record(us_between(s.decoded, s.estimated));
        command.record(us_between(s.estimated, s.commanded));
        write.record(us_between(s.commanded, written));
    }

    pub fn figures(&self) -> LatencyFigures {
        let [estimate, command, write] = &self.stages;
        LatencyFigures {
            total: self.total.percentiles(),
            stages: StageFigures {
                decode_to_estimate: estimate.percentiles(),
                estimate_to_command: command.percentiles(),
                command_to_write: write.percentiles(),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn percentiles_are_those_of_the_sorted_samples() {
        let h = Histogram::default();
        let mut samples: Vec<u32> = (0..1000).map(|k| (k * 7919) % 613).collect();
        samples.push(25_000);
        for &s in &samples {
            h.record(s);
        }
        samples.sort_unstable();
        let rank = |q: f64| samples[((samples.len() - 1) as f64 * q).round() as usize];
        let p = h.percentiles();
        assert_eq!((p.p50, p.p99, p.max), (rank(0.5), rank(0.99), 25_000));
        assert_eq!(h.count(), 1001);
        let newest: Vec<u32> = h.recent(3).collect();
        assert_eq!(newest, vec![25_000, (999 * 7919) % 613, (998 * 7919) % 613]);
    }

    #[test]
    fn a_command_is_split_into_its_stages() {
        let log = LatencyLog::default();
        let t0 = Instant::now();
        let s = Stamps {
            decoded: t0,
            estimated: t0 + Duration::from_micros(12),
            commanded: t0 + Duration::from_micros(20),
        };
        log.record(&s, t0 + Duration::from_micros(55));
        let f = log.figures();
        assert_eq!(f.total.max, 55);
        assert_eq!(f.stages.decode_to_estimate.p50, 12);
        assert_eq!(f.stages.estimate_to_command.p50, 8);
        assert_eq!(f.stages.command_to_write.p99, 35);
        assert_eq!(LatencyLog::default().figures(), LatencyFigures::default());
    }
}
