//! The IMU's sensor health beyond the frame's checksum: a gyro whose output stops changing
//! (a stuck sensor, a frozen bus) sends well-formed frames that read a still vehicle. Not in
//! the original's spec (it trusted every frame that decoded).
//!
//! The rule is PX4's `DataValidator` stale check: a reading that repeats exactly, sample
//! after sample, is not a sensor's. The ITG-3200's noise is several counts per axis: the 2012
//! flight never repeats all three axes on two frames in a row (1631 frames), the simulator
//! about once in 1000 frames and never on three, so [`STUCK_FRAMES`] identical frames are not
//! a still vehicle (a run of five by chance, were frames independent at the simulator's rate:
//! about one frame in 10¹²). A quiet sensor at rest flagged by chance refuses the arm (the
//! `estimator` check) until a new calibration watches it again; no real sensor's still noise
//! has been measured for it.

use super::frame::RawFrame;

/// Consecutive frames whose three gyro counts are identical that mark the gyro stuck:
/// 0.05 s at 100 Hz. Every frame before it is seen is flown against the stuck rate: with ten
/// (0.1 s) a square mission's controller had turned the vehicle at up to 1.3 rad/s unseen by
/// then, and the landing on the model's attitude touched down above 1 m/s in 3 of 60 (none
/// with five; `docs/src/flying.md`, Known limits).
pub const STUCK_FRAMES: u32 = 5;

/// Watches the raw gyro counts. Once stuck, the gyro stays lost until the watch is started
/// again (a new calibration): a sensor that froze once is not trusted again mid-flight (the
/// estimate it fed has been flown without it).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GyroWatch {
    last: Option<[i16; 3]>,
    /// Frames in a row equal to `last`, the first included.
    same: u32,
    lost: bool,
}

impl GyroWatch {
    /// Takes one frame; `true` once the gyro is lost.
    pub fn on_frame(&mut self, frame: &RawFrame) -> bool {
        self.same = if self.last == Some(frame.gyro) {
            self.same.saturating_add(1)
        } else {
            1
        };
        self.last = Some(frame.gyro);
        self.lost |= self.same >= STUCK_FRAMES;
        self.lost
    }

    pub fn lost(&self) -> bool {
        self.lost
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(gyro: [i16; 3]) -> RawFrame {
        RawFrame {
            gyro,
            ..RawFrame::default()
        }
    }

    #[test]
    fn a_gyro_repeating_its_counts_is_lost_at_the_limit_and_stays_lost() {
        let mut w = GyroWatch::default();
        for i in 1..STUCK_FRAMES {
            assert!(!w.on_frame(&frame([3, -2, 7])), "frame {i}");
        }
        assert!(w.on_frame(&frame([3, -2, 7])));
        assert!(w.on_frame(&frame([4, -1, 9])) && w.lost());
    }

    #[test]
    fn one_axis_changing_keeps_the_gyro_alive() {
        let mut w = GyroWatch::default();
        for i in 0..10 * STUCK_FRAMES {
            // Two axes frozen, the third moving by one count: a real, quiet sensor.
            let z = (i % 2) as i16;
            assert!(!w.on_frame(&frame([3, -2, z])));
        }
    }
}
