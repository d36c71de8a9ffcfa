//! Where the filter's GPS samples come from: none, a recorded gps.log, the original's fake-GPS
//! clock, or live gpsd fixes (spec 7 with ERRATA 5 and 10).

use crate::core::gps::{FakeGpsClock, FakePositions, GpsSample, RecordedGps};

/// Where the filter's GPS samples come from.
#[derive(Debug, Clone)]
pub enum GpsFeed {
    Off,
    /// Samples stamped in a log, fused by the first later Kalman step (ERRATA 5).
    Recorded(RecordedGps),
    /// The fake-GPS rule on the motor-command clock (ERRATA 10): a sample produced after
    /// command k is fused by Kalman step k + 1.
    Clock {
        clock: FakeGpsClock,
        positions: FakePositions,
        pending: Option<GpsSample>,
    },
    /// Live samples (gpsd): whatever arrived since the previous step.
    Live(Option<GpsSample>),
}

impl GpsFeed {
    pub fn fake(positions: FakePositions) -> Self {
        GpsFeed::Clock {
            clock: FakeGpsClock::default(),
            positions,
            pending: None,
        }
    }

    /// After the motor command at `t_cmd_us`; `true` when a fake sample was produced.
    pub fn after_command(&mut self, t_cmd_us: i64) -> bool {
        if let GpsFeed::Clock {
            clock,
            positions,
            pending,
        } = self
            && clock.on_motor_command(t_cmd_us)
        {
            *pending = Some(positions.next_sample());
            return true;
        }
        false
    }

    /// A live sample arrived (gpsd): it is fused by the next step.
    pub fn offer_live(&mut self, sample: GpsSample) {
        if let GpsFeed::Live(slot) = self {
            *slot = Some(sample);
        }
    }

    /// The sample to fuse in the Kalman step at `t_us`, if any.
    pub fn for_step(&mut self, t_us: i64) -> Option<GpsSample> {
        match self {
            GpsFeed::Off => None,
            GpsFeed::Recorded(r) => r.take_before(t_us),
            GpsFeed::Clock { pending, .. } => pending.take(),
            GpsFeed::Live(s) => s.take(),
        }
    }
}
