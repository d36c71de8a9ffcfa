//! Motor commands: saturation, the flight ramp, rad/s ↔ I2C byte, the ESC addresses and trims,
//! and the ESC start-up saw-tooth ramp, as pure generators for the ESC writer and the flight
//! state machine.
//!
//! Spec sections 4.2 (saturation), 6.1 (rad/s → I2C), 6.3 (motor order, addresses, registers,
//! trims), 6.4 (ESC start-up ramp), 8.3 step 11 (flight ramp) and ERRATA 6. Speeds in rad/s.

use crate::core::model::MotorLimits;

/// Kalman steps of the flight ramp (`STARTUP_SAMPLES`).
pub const FLIGHT_RAMP_STEPS: u32 = 100;

/// Offset the flight ramp adds to the controller output at Kalman step `step` (1-based):
/// `−(100 − step)·(w_hover − w_min)/100` for steps 1–99, 0 from step 100 on (the original's
/// linear branch, despite its `RAMP_LINEAR = 0` name).
pub fn flight_ramp_offset_rad_s(step: u32, limits: &MotorLimits) -> f64 {
    if step >= FLIGHT_RAMP_STEPS {
        return 0.0;
    }
    -f64::from(FLIGHT_RAMP_STEPS - step) * (limits.w_hover_rad_s - limits.w_min_rad_s)
        / f64::from(FLIGHT_RAMP_STEPS)
}

/// Saturates each speed to [w_min, w_max] (`mot_set_vel_rads`); returns how many were clamped.
/// A non-finite speed is clamped to w_min: a NaN must never reach the motors as a high value.
pub fn saturate(w: &mut [f64; 4], limits: &MotorLimits) -> usize {
    let mut clamped = 0;
    for v in w.iter_mut() {
        let s = if v.is_nan() {
            limits.w_min_rad_s
        } else {
            v.clamp(limits.w_min_rad_s, limits.w_max_rad_s)
        };
        clamped += usize::from(s != *v);
        *v = s;
    }
    clamped
}

/// The command actually sent at Kalman step `step` (1-based) for controller output `w`:
/// while ramping (steps 1–99) `max(w_min, w + offset)`, then `w`; both saturated (spec 8.3
/// step 11, 4.2).
pub fn command_for_step(w: &[f64; 4], step: u32, limits: &MotorLimits) -> [f64; 4] {
    let offset = flight_ramp_offset_rad_s(step, limits);
    let mut out = w.map(|v| {
        if step < FLIGHT_RAMP_STEPS {
            (v + offset).max(limits.w_min_rad_s)
        } else {
            v
        }
    });
    saturate(&mut out, limits);
    out
}

/// Highest value the ESC driver accepts (`MOT_I2C_MAX`).
pub const I2C_MAX: u8 = 220;
/// Idle command (`MOT_I2C_IDLE`), ≈ 109 rad/s.
pub const I2C_IDLE: u8 = 50;
/// All four commands above this start the ESCs (`MIN_SPEED`).
pub const I2C_START_THRESHOLD: u8 = 45;

const FIT_A3: f64 = 3.25038742351062e-06;
const FIT_A2: f64 = -0.00107345094348345;
const FIT_A1: f64 = 0.552199572510559;

/// The cubic fit of spec 6.1 without rounding.
pub fn i2c_fit(w_rad_s: f64) -> f64 {
    FIT_A3 * w_rad_s * w_rad_s * w_rad_s + FIT_A2 * w_rad_s * w_rad_s + FIT_A1 * w_rad_s
}

/// rad/s → I2C speed value: the cubic fit rounded half away from zero, limited to
/// [0, `I2C_MAX`] (the driver refuses more; a non-finite speed gives 0).
pub fn i2c_from_rad_s(w_rad_s: f64) -> u8 {
    let v = i2c_fit(w_rad_s).round();
    if v.is_nan() || v <= 0.0 {
        0
    } else if v >= f64::from(I2C_MAX) {
        I2C_MAX
    } else {
        v as u8
    }
}

/// I2C speed value → rad/s: the inverse of the (increasing) cubic fit, for the simulated ESCs.
pub fn rad_s_from_i2c(value: u8) -> f64 {
    let target = f64::from(value);
    let (mut lo, mut hi) = (0.0f64, 600.0f64);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if i2c_fit(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// The ESC start threshold in rad/s: the speed of the lowest I2C value above
/// `I2C_START_THRESHOLD`, about 96.0 rad/s. The driver starts the ESCs only when all four
/// values exceed the threshold (spec 6.4, `MIN_SPEED`): the lowest speeds it takes as running.
/// Slower commands are values it would not start at, down to 0, which stops a motor. So the
/// slowest flight command (w_min) must stay above this speed. A function, not a constant: the inverse of the fit is
/// not a `const fn`.
pub fn esc_start_rad_s() -> f64 {
    rad_s_from_i2c(I2C_START_THRESHOLD + 1)
}

/// The top of the ESC's byte range in rad/s: the speed of `I2C_MAX` (368.16 rad/s, the 2012
/// flights' `MOT_W_MAX`), rounded down to 0.1 rad/s so that a bound built from it prints as
/// it is checked. Every faster command is sent as `I2C_MAX`, so a w_max above it would let the
/// controller count on thrust the motors never give.
pub fn esc_max_rad_s() -> f64 {
    (rad_s_from_i2c(I2C_MAX) * 10.0).floor() / 10.0
}

/// ESC registers (SMBus write-byte-data, spec 6.3).
pub const REG_ENABLE: u8 = 0xA0;
pub const REG_DISABLE: u8 = 0xA1;
pub const REG_SPEED: u8 = 0xA2;

/// Where each motor is and how its speed is trimmed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MotorMap {
    /// I2C address of motors m0..m3.
    pub addresses: [u8; 4],
    /// Trim added to the speed value of m0..m3 while running.
    pub trims: [i16; 4],
}

impl MotorMap {
    /// The uQuad's wiring (spec 6.3): m0 → 0x69, m1 → 0x6B, m2 → 0x6A, m3 → 0x68, with the
    /// driver's trims +15 (0x69), +15 (0x6A), −18 (0x6B), −9 (0x68).
    pub const UQUAD: MotorMap = MotorMap {
        addresses: [0x69, 0x6B, 0x6A, 0x68],
        trims: [15, -18, 15, -9],
    };

    /// The speed-register writes for four I2C values, in motor order: (address, register,
    /// value + trim). The sum saturates to 0..=255 (the original wrapped, which would turn a
    /// small command with a negative trim into full throttle); 0 stays 0 (stopped).
    pub fn speed_writes(&self, values: &[u8; 4]) -> [(u8, u8, u8); 4] {
        std::array::from_fn(|m| {
            let v = if values[m] == 0 {
                0
            } else {
                (i16::from(values[m]) + self.trims[m]).clamp(0, 255) as u8
            };
            (self.addresses[m], REG_SPEED, v)
        })
    }
}

/// One action of the ESC start-up sequence, at `t_us` after its start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EscAction {
    /// Enable every ESC (write 0 to the enable register).
    EnableAll,
    /// Write this speed value to every ESC (no trims during the ramp).
    SpeedAll(u8),
}

/// Wait after enabling before the ramp, µs.
pub const ESC_ENABLE_WAIT_US: u64 = 420_000;
/// Spacing of the ramp's sub-steps, µs.
pub const ESC_RAMP_STEP_US: u64 = 1_235;

/// How long the start-up ramp takes, µs: from the enable to a sub-step after its last write.
pub fn esc_startup_ramp_us() -> u64 {
    esc_startup_ramp().last().map_or(0, |(at, _)| at) + ESC_RAMP_STEP_US
}

/// The driver's start-up ramp (spec 6.4): enable, wait 420 ms, then for r = 30..=49, 2·r
/// sub-steps 1235 µs apart writing r − 25 when the sub-step index j is a multiple of 7 and
/// r + 25 otherwise: 1580 writes, about 1.95 s.
pub fn esc_startup_ramp() -> impl Iterator<Item = (u64, EscAction)> {
    let ramp = (30u8..=49).flat_map(|r| (0..2 * u32::from(r)).map(move |j| (r, j)));
    std::iter::once((0, EscAction::EnableAll)).chain(ramp.enumerate().map(|(n, (r, j))| {
        let v = if j % 7 == 0 { r - 25 } else { r + 25 };
        (
            ESC_ENABLE_WAIT_US + n as u64 * ESC_RAMP_STEP_US,
            EscAction::SpeedAll(v),
        )
    }))
}

/// Sets the four speeds' common part so that their thrust is `share` of the weight of
/// `mass_kg`, the controller's differences between them (the attitude's) kept as they are:
/// the vertical flown on thrust alone, whatever the controller's own collective asked, and
/// the attitude still the controller's (a scale would multiply its differences with it).
pub fn set_thrust(w_rad_s: &mut [f64; 4], share: f64, mass_kg: f64) {
    let mean_rad_s = w_rad_s.iter().sum::<f64>() / 4.0;
    let common_rad_s = crate::core::model::w_hover_rad_s(share.max(0.0) * mass_kg);
    if !(mean_rad_s.is_finite() && common_rad_s.is_finite()) {
        return;
    }
    for w in w_rad_s.iter_mut() {
        *w += common_rad_s - mean_rad_s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> MotorLimits {
        MotorLimits::new(1.55, 368.0)
    }

    #[test]
    fn ramp_offset_is_linear_and_ends_at_step_100() {
        let l = limits();
        let span = l.w_hover_rad_s - l.w_min_rad_s;
        assert!((flight_ramp_offset_rad_s(1, &l) + 0.99 * span).abs() < 1e-12);
        assert!((flight_ramp_offset_rad_s(99, &l) + 0.01 * span).abs() < 1e-12);
        assert_eq!(flight_ramp_offset_rad_s(100, &l), 0.0);
        assert_eq!(flight_ramp_offset_rad_s(5000, &l), 0.0);
    }

    #[test]
    fn flight_ramp_sequence() {
        let l = limits();
        let span = l.w_hover_rad_s - l.w_min_rad_s;
        let w = [l.w_hover_rad_s; 4];
        let seq: Vec<f64> = (1..=101).map(|k| command_for_step(&w, k, &l)[0]).collect();
        for (i, v) in seq.iter().enumerate() {
            let k = i as u32 + 1;
            let expected = if k < 100 {
                (l.w_hover_rad_s - f64::from(100 - k) * span / 100.0).max(l.w_min_rad_s)
            } else {
                l.w_hover_rad_s
            };
            assert!((v - expected).abs() < 1e-12, "step {k}: {v} vs {expected}");
        }
        // Increasing from just above w_min to w_hover.
        assert!(seq.windows(2).all(|p| p[1] >= p[0]));
        // Far below: floored at w_min; far above: capped at w_max.
        assert_eq!(command_for_step(&[0.0; 4], 5, &l)[0], l.w_min_rad_s);
        assert_eq!(command_for_step(&[1e4; 4], 120, &l)[0], 368.0);
        assert_eq!(command_for_step(&[f64::NAN; 4], 120, &l)[0], l.w_min_rad_s);
    }

    #[test]
    fn i2c_fit_matches_the_spec_table() {
        for (w, v) in [
            (109.0, 51.65),
            (229.84, 109.68),
            (298.92, 155.96),
            (312.50, 166.93),
            (368.0, 219.82),
            (387.0, 241.33),
        ] {
            assert!((i2c_fit(w) - v).abs() < 0.01, "{w}: {}", i2c_fit(w));
        }
        assert_eq!(i2c_from_rad_s(368.0), 220);
        assert_eq!(i2c_from_rad_s(387.0), I2C_MAX);
        assert_eq!(i2c_from_rad_s(298.92), 156);
        assert_eq!(i2c_from_rad_s(229.84), 110);
        assert_eq!(i2c_from_rad_s(-5.0), 0);
        assert_eq!(i2c_from_rad_s(f64::NAN), 0);
        // Idle 50 is 105.2 rad/s by the new fit (the spec's 109 rad/s is the old fit's).
        assert!((rad_s_from_i2c(I2C_IDLE) - 105.21).abs() < 0.01);
        for v in [1u8, 50, 110, 156, 220] {
            assert_eq!(i2c_from_rad_s(rad_s_from_i2c(v)), v);
        }
    }

    #[test]
    fn esc_range_in_rad_s() {
        let start = esc_start_rad_s();
        assert!((start - 96.01).abs() < 0.01, "{start}");
        // Every speed above the threshold is sent as a value the driver starts at.
        assert_eq!(i2c_from_rad_s(start.next_up()), I2C_START_THRESHOLD + 1);
        assert_eq!(i2c_from_rad_s(start - 1.2), I2C_START_THRESHOLD);
        assert_eq!(esc_max_rad_s(), 368.1);
        assert_eq!(i2c_from_rad_s(esc_max_rad_s()), I2C_MAX);
        assert!(esc_max_rad_s() >= crate::core::model::W_MAX_2012_RAD_S);
    }

    #[test]
    fn speed_writes_follow_the_wiring_and_trims() {
        let w = MotorMap::UQUAD.speed_writes(&[100, 100, 100, 0]);
        assert_eq!(
            w,
            [
                (0x69, REG_SPEED, 115),
                (0x6B, REG_SPEED, 82),
                (0x6A, REG_SPEED, 115),
                (0x68, REG_SPEED, 0)
            ]
        );
        // Saturating, not wrapping.
        let w = MotorMap::UQUAD.speed_writes(&[5, 5, 250, 5]);
        assert_eq!([w[0].2, w[1].2, w[2].2, w[3].2], [20, 0, 255, 0]);
    }

    #[test]
    fn esc_startup_ramp_exact_sequence() {
        let seq: Vec<(u64, EscAction)> = esc_startup_ramp().collect();
        assert_eq!(seq[0], (0, EscAction::EnableAll));
        let writes = &seq[1..];
        assert_eq!(writes.len(), 1580);
        // r = 30: j = 0 -> 5, j = 1..6 -> 55, j = 7 -> 5 ...
        assert_eq!(writes[0], (420_000, EscAction::SpeedAll(5)));
        assert_eq!(writes[1], (421_235, EscAction::SpeedAll(55)));
        assert_eq!(writes[7].1, EscAction::SpeedAll(5));
        // r = 31 starts after 60 sub-steps.
        assert_eq!(writes[60].1, EscAction::SpeedAll(6));
        assert_eq!(writes[61].1, EscAction::SpeedAll(56));
        let last = writes.last().unwrap();
        assert_eq!(last.1, EscAction::SpeedAll(74));
        assert_eq!(last.0, 420_000 + 1579 * 1235);
        let values: Vec<u8> = writes
            .iter()
            .map(|(_, a)| match a {
                EscAction::SpeedAll(v) => *v,
                EscAction::EnableAll => 0,
            })
            .collect();
        assert_eq!(*values.iter().min().unwrap(), 5);
        assert_eq!(*values.iter().max().unwrap(), 74);
        assert!(
            values
                .iter()
                .all(|v| (5..=24).contains(v) || (55..=74).contains(v))
        );
    }

    #[test]
    fn a_thrust_set_outright_keeps_the_attitudes_differences() {
        let m = 1.55;
        let w_h = crate::core::model::w_hover_rad_s(m);
        let weight = m * crate::core::model::GRAVITY_M_S2;
        let thrust = |w: &[f64; 4]| {
            w.iter()
                .map(|&v| crate::core::model::thrust_n(v))
                .sum::<f64>()
        };
        // Whatever collective the controller asked (far under or over the weight), the
        // thrust is the share asked, and the differences between the motors stay.
        for collective in [0.3, 1.0, 1.4] {
            let c = w_h * collective;
            let mut w = [c + 10.0, c - 10.0, c, c];
            set_thrust(&mut w, 0.8, m);
            let t = thrust(&w);
            assert!((t / weight - 0.8).abs() < 0.01, "{t} of {weight}");
            assert!((w[0] - w[1] - 20.0).abs() < 1e-9 && (w[2] - w[3]).abs() < 1e-9);
        }
        let mut nan = [f64::NAN; 4];
        set_thrust(&mut nan, 0.8, m);
        assert!(
            nan.iter().all(|v| v.is_nan()),
            "left to the saturation's own rule"
        );
    }
}
