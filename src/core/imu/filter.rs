//! The 6-tap FIR pre-filter over raw IMU frames.
//!
//! Spec section 2.3 with ERRATA 1: h = [0.2, 0.2, 0.2, 0.2, 0.1, 0.1], h[0] on the newest
//! frame, applied to every raw field (acc, gyro, magn, temperature and pressure). The sum is
//! accumulated in `f64` from 0, newest first, and truncated toward zero back into the integer
//! field, exactly as the original stored it; any other order flips about 1 % of the values by
//! one count and the logs no longer match.

use super::frame::RawFrame;

/// Number of taps.
pub const FIR_LEN: usize = 6;
/// Coefficients, newest frame first.
pub const FIR_TAPS: [f64; FIR_LEN] = [0.2, 0.2, 0.2, 0.2, 0.1, 0.1];

/// Ring of the last six raw frames. It spans the calibration frames too, as the original's did.
#[derive(Debug, Clone, Default)]
pub struct Fir {
    ring: [RawFrame; FIR_LEN],
    /// Index where the next frame goes.
    next: usize,
    /// Frames seen, saturating at `FIR_LEN`.
    count: usize,
}

impl Fir {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn push(&mut self, f: RawFrame) {
        self.ring[self.next] = f;
        self.next = (self.next + 1) % FIR_LEN;
        self.count = (self.count + 1).min(FIR_LEN);
    }

    /// The filter has a full window.
    pub fn ready(&self) -> bool {
        self.count == FIR_LEN
    }

    /// The `i`-th newest frame (0 = newest).
    fn back(&self, i: usize) -> &RawFrame {
        &self.ring[(self.next + FIR_LEN - 1 - i) % FIR_LEN]
    }

    fn tap(&self, field: impl Fn(&RawFrame) -> f64) -> f64 {
        let mut acc = 0.0;
        for (i, h) in FIR_TAPS.iter().enumerate() {
            acc += h * field(self.back(i));
        }
        acc
    }

    /// The filtered frame (fields truncated toward zero), or `None` until six frames arrived.
    /// `T_us` is the newest frame's.
    pub fn output(&self) -> Option<RawFrame> {
        if !self.ready() {
            return None;
        }
        // A convex combination of i16 values stays in i16 range: `as` only truncates the fraction.
        let axis = |sel: fn(&RawFrame) -> [i16; 3]| -> [i16; 3] {
            std::array::from_fn(|k| self.tap(|f| f64::from(sel(f)[k])).trunc() as i16)
        };
        Some(RawFrame {
            t_us: self.back(0).t_us,
            acc: axis(|f| f.acc),
            gyro: axis(|f| f.gyro),
            magn: axis(|f| f.magn),
            temp_dc: self.tap(|f| f64::from(f.temp_dc)).trunc() as i16,
            pres_pa: self.tap(|f| f64::from(f.pres_pa)).trunc() as u32,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ready_after_six_and_truncates() {
        let mut fir = Fir::new();
        for v in 0..5i16 {
            fir.push(RawFrame {
                acc: [v, -v, 0],
                ..RawFrame::default()
            });
            assert!(fir.output().is_none());
        }
        fir.push(RawFrame {
            acc: [5, -5, 0],
            t_us: 77,
            ..RawFrame::default()
        });
        let out = fir.output().unwrap();
        // 0.2*(5+4+3+2) + 0.1*(1+0) = 2.9 -> 2; the negative side truncates toward zero: -2.
        assert_eq!(out.acc, [2, -2, 0]);
        assert_eq!(out.t_us, 77);
    }
}
