//! What a flight's takeoff and landing measured — the climb's overshoot, the touchdown's speed
//! and place — on whatever the caller samples: the estimate (`fly`) or the true vehicle (the
//! simulator). Not in the original's spec.

use super::Mode;
use std::collections::VecDeque;

/// The figures a report shows.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Figures {
    pub takeoff: Option<Takeoff>,
    pub touchdown: Option<Touchdown>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Takeoff {
    /// The climb asked for, m.
    pub target_m: f64,
    /// How far the climb's first peak went past the height then held, m (0 if it did not).
    pub overshoot_m: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Touchdown {
    pub t_us: i64,
    /// The fastest descent in the second before, m/s.
    pub v_m_s: f64,
    /// Horizontal distance from where the takeoff started, m.
    pub from_takeoff_m: f64,
}

/// The hold's height is averaged over this many samples after the climb's peak (10 s at
/// 100 Hz).
const HOLD_SAMPLES: u32 = 1000;

/// The climb's first peak against the height then held: the step response's overshoot, which
/// a constant error of the altitude estimate does not change.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ClimbTrace {
    target_m: Option<f64>,
    ground_m: f64,
    peak_m: f64,
    peaked: bool,
    hold_sum_m: f64,
    hold_n: u32,
    /// The sticks took over after the takeoff: a later hold is not its settling.
    sticks: bool,
}

impl ClimbTrace {
    /// A takeoff from `ground_m` asking for `height_m` more.
    pub fn begin(&mut self, ground_m: f64, height_m: f64) {
        *self = ClimbTrace {
            target_m: Some(height_m),
            ground_m,
            peak_m: ground_m,
            ..ClimbTrace::default()
        };
    }

    /// One sample of the height `z_m` and vertical speed `vz_m_s` in `mode`.
    pub fn sample(&mut self, mode: Mode, z_m: f64, vz_m_s: f64) {
        match mode {
            Mode::Takeoff => self.peak_m = self.peak_m.max(z_m),
            Mode::Position | Mode::Altitude => self.sticks = true,
            Mode::Hold if self.sticks => {}
            Mode::Hold if !self.peaked => {
                self.peak_m = self.peak_m.max(z_m);
                self.peaked = vz_m_s <= 0.0;
            }
            Mode::Hold if self.hold_n < HOLD_SAMPLES => {
                self.hold_sum_m += z_m;
                self.hold_n += 1;
            }
            _ => {}
        }
    }

    pub fn takeoff(&self) -> Option<Takeoff> {
        let target_m = self.target_m?;
        let held_m = if self.hold_n > 0 {
            self.hold_sum_m / f64::from(self.hold_n)
        } else {
            self.ground_m + target_m
        };
        Some(Takeoff {
            target_m,
            overshoot_m: (self.peak_m - held_m).max(0.0),
        })
    }
}

/// The descent speeds of the last second.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DescentTrace {
    recent: VecDeque<(i64, f64)>,
}

impl DescentTrace {
    pub fn sample(&mut self, t_us: i64, vz_m_s: f64) {
        while self
            .recent
            .front()
            .is_some_and(|(t, _)| t_us - t > 1_000_000)
        {
            self.recent.pop_front();
        }
        self.recent.push_back((t_us, vz_m_s.abs()));
    }

    /// The fastest of the last second, m/s.
    pub fn peak_m_s(&self) -> f64 {
        self.recent.iter().map(|(_, v)| *v).fold(0.0, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_overshoot_is_the_peak_past_the_height_then_held() {
        let mut c = ClimbTrace::default();
        c.begin(0.1, 1.0);
        for (mode, z, vz) in [
            (Mode::Takeoff, 0.5, 0.5),
            (Mode::Takeoff, 1.0, 0.4),
            (Mode::Hold, 1.16, 0.1),
            (Mode::Hold, 1.18, -0.01),
            (Mode::Hold, 1.12, -0.1),
            (Mode::Hold, 1.14, 0.0),
        ] {
            c.sample(mode, z, vz);
        }
        let t = c.takeoff().unwrap();
        assert_eq!(t.target_m, 1.0);
        assert!((t.overshoot_m - 0.05).abs() < 1e-12, "{t:?}");
    }

    #[test]
    fn descents_keep_their_last_second() {
        let mut d = DescentTrace::default();
        d.sample(0, -0.9);
        d.sample(500_000, -0.3);
        assert_eq!(d.peak_m_s(), 0.9);
        d.sample(1_400_000, -0.1);
        assert_eq!(d.peak_m_s(), 0.3);
    }
}
