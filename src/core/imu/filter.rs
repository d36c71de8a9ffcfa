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

    /// The filtered frame (fields truncated toward zero), or `None` until six frames arrived.
    /// `T_us` is the newest frame's.
    pub fn output(&self) -> Option<RawFrame> {
        self.filtered().map(|(frame, _)| frame)
    }

    /// [`Fir::output`], with the filtered pressure as the sum gives it, before the
    /// truncation, Pa: truncating takes 0.45 Pa off on average (the sum's tenths), which
    /// reads as 0.04 m of altitude.
    pub fn filtered(&self) -> Option<(RawFrame, f64)> {
        let sum = self.sums()?;
        // A float's `as` cast truncates toward zero (and saturates), as the original's
        // assignment did.
        let axis = |k: usize| -> [i16; 3] { std::array::from_fn(|j| sum[k + j] as i16) };
        let frame = RawFrame {
            t_us: self.ring[self.newest()].t_us,
            acc: axis(0),
            gyro: axis(3),
            magn: axis(6),
            temp_dc: sum[9] as i16,
            pres_pa: sum[PRESSURE] as u32,
        };
        Some((frame, sum[PRESSURE]))
    }

    fn newest(&self) -> usize {
        (self.next + FIR_LEN - 1) % FIR_LEN
    }

    /// Every field of every frame in the window as a float, newest frame first; then each
    /// field's sum, accumulated from 0, newest first (see the module's note), all fields side
    /// by side. `None` until the window is full.
    fn sums(&self) -> Option<[f64; FIELDS]> {
        if !self.ready() {
            return None;
        }
        let newest = self.newest();
        let window: [[f64; FIELDS]; FIR_LEN] =
            std::array::from_fn(|i| fields(&self.ring[(newest + FIR_LEN - i) % FIR_LEN]));
        let mut sum = [0.0; FIELDS];
        for (h, frame) in FIR_TAPS.iter().zip(&window) {
            for (s, v) in sum.iter_mut().zip(frame) {
                *s += h * v;
            }
        }
        Some(sum)
    }
}

/// The pressure's place among the filtered fields.
const PRESSURE: usize = 10;

/// The filtered fields of a frame: acc, gyro, magn (three each), temperature, pressure.
const FIELDS: usize = 11;

/// A frame's filtered fields as floats, in [`FIELDS`]' order.
fn fields(f: &RawFrame) -> [f64; FIELDS] {
    let [a0, a1, a2] = f.acc.map(f64::from);
    let [g0, g1, g2] = f.gyro.map(f64::from);
    let [m0, m1, m2] = f.magn.map(f64::from);
    [
        a0,
        a1,
        a2,
        g0,
        g1,
        g2,
        m0,
        m1,
        m2,
        f64::from(f.temp_dc),
        f64::from(f.pres_pa),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pressure_is_also_given_before_its_truncation() {
        let mut fir = Fir::new();
        for p in [100_000, 100_001, 100_000, 100_001, 100_000, 100_001] {
            fir.push(RawFrame {
                pres_pa: p,
                ..RawFrame::default()
            });
        }
        // Newest first: 0.2·(100001 + 100000 + 100001 + 100000) + 0.1·(100001 + 100000).
        let (frame, exact) = fir.filtered().expect("a full window");
        assert!((exact - 100_000.5).abs() < 1e-6, "{exact}");
        assert_eq!(frame.pres_pa, 100_000);
        assert_eq!(fir.output(), Some(frame));
    }

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
