//! How fresh the IMU's verdict is before a flight: when the newest frame arrived and when the
//! frames last resumed after a silence longer than the watchdog's IMU timeout. An `arm` is
//! judged only on frames arriving now and steadily for [`STEADY_US`]; a run that asked to fly
//! and ends with the IMU silent says why it could not start. (No spec section: the original
//! had no pre-arm checks; this is the same IMU timeout its watchdog applies in flight.)

/// Frames must have arrived without a silence for this long before an `arm` trusts them, µs.
pub const STEADY_US: i64 = 1_000_000;

/// The IMU's arrivals, by their frame stamps (µs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuWatch {
    /// A gap between frames longer than this is a silence (`watchdog.imu_timeout_ms`).
    silence_max_us: i64,
    last_us: Option<i64>,
    /// The newest silence: (its last frame before, the frame that ended it).
    gap: Option<(i64, i64)>,
}

impl ImuWatch {
    /// A watch that never calls a gap a silence (a replay judges on recorded verdicts).
    pub const LENIENT: ImuWatch = ImuWatch {
        silence_max_us: i64::MAX,
        last_us: None,
        gap: None,
    };

    pub fn new(silence_max_us: i64) -> Self {
        ImuWatch {
            silence_max_us,
            ..ImuWatch::LENIENT
        }
    }

    /// A frame arrived at `t_us`.
    pub fn on_frame(&mut self, t_us: i64) {
        if let Some(last) = self.last_us
            && t_us.saturating_sub(last) > self.silence_max_us
        {
            self.gap = Some((last, t_us));
        }
        self.last_us = Some(self.last_us.map_or(t_us, |l| l.max(t_us)));
    }

    /// Why the frames do not vouch for the IMU at `t_us`: silent now, or resumed less than
    /// [`STEADY_US`] ago. `None` before the first frame (the settling says so).
    pub fn stale(&self, t_us: i64) -> Option<String> {
        let last = self.last_us?;
        let silent_us = t_us.saturating_sub(last);
        if silent_us > self.silence_max_us {
            return Some(format!(
                "imu: no frame for {:.2} s (watchdog.imu_timeout_ms = {} ms): its verdict is stale",
                silent_us as f64 / 1e6,
                self.silence_max_us / 1000
            ));
        }
        let (before, after) = self.gap?;
        let steady_us = t_us.saturating_sub(after);
        (steady_us < STEADY_US).then(|| {
            format!(
                "imu: frames resumed {:.2} s ago after {:.2} s without; {} s of steady frames needed",
                steady_us as f64 / 1e6,
                (after - before) as f64 / 1e6,
                STEADY_US as f64 / 1e6
            )
        })
    }

    /// The IMU's silence at the run's end `end_us` when longer than `limit_us`.
    pub fn silent_at(&self, end_us: i64, limit_us: i64) -> Option<String> {
        match self.last_us {
            None => Some("no IMU frame arrived".into()),
            Some(last) if end_us.saturating_sub(last) > limit_us => Some(format!(
                "the IMU was silent from {:.2} s to the end ({:.2} s)",
                last as f64 / 1e6,
                end_us as f64 / 1e6
            )),
            Some(_) => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_verdict_holds_while_frames_arrive_steadily() {
        let mut w = ImuWatch::new(12_000);
        assert_eq!(w.stale(0), None, "no frame yet: the settling decides");
        for t in (0..2_000_000).step_by(10_000) {
            w.on_frame(t);
        }
        assert_eq!(w.stale(2_000_000), None);
        // Silent for 2.4 s: stale until frames have come steadily for a second again.
        let why = w.stale(4_400_000).unwrap();
        assert!(why.contains("no frame for 2.41 s"), "{why}");
        w.on_frame(4_400_000);
        let why = w.stale(4_410_000).unwrap();
        assert!(
            why.contains("resumed 0.01 s ago after 2.41 s without"),
            "{why}"
        );
        for t in (4_410_000..5_410_000).step_by(10_000) {
            w.on_frame(t);
        }
        assert_eq!(w.stale(5_410_000), None);
        assert!(ImuWatch::LENIENT.stale(1).is_none());
    }

    #[test]
    fn a_run_that_ends_with_the_imu_silent_says_so() {
        let mut w = ImuWatch::new(12_000);
        assert_eq!(w.silent_at(5, 1_000_000).unwrap(), "no IMU frame arrived");
        w.on_frame(1_000_000);
        assert_eq!(w.silent_at(1_500_000, 1_000_000), None);
        let why = w.silent_at(20_000_000, 1_000_000).unwrap();
        assert!(
            why.contains("silent from 1.00 s to the end (20.00 s)"),
            "{why}"
        );
    }
}
