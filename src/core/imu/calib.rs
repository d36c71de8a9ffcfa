//! IMU calibration: the `imu_calib.txt` model, raw counts → SI units with temperature
//! compensation, the start-up null estimate, Euler angles and barometric altitude.
//!
//! Spec sections 2.1 (file format), 2.2 (conversion), 2.4 (null estimate), 2.6 (Euler angles).
//! Units: acceleration m/s², rates rad/s, angles rad, temperature °C, altitude m, pressure Pa.
//! Sums are written out in the original's order (row by row, column 0 first) so the results
//! agree with its logs to print precision.

use super::frame::RawFrame;
use crate::core::math;
use crate::core::numfile::{self, NumberError};

/// Numbers in a complete `imu_calib.txt` (3 × 12 + 1 + 1 + 3 + 3 + 1).
pub const CALIB_NUMBERS: usize = 45;
/// The original's π (spec 4.1), used where its results depend on it.
#[allow(clippy::approx_constant)]
pub const PI_ORIGINAL: f64 = 3.1415926;
/// `PRESS_K` of the barometric formula, m.
pub const PRESS_K_M: f64 = 44330.0;
/// `PRESS_EXP` = 1/5.255, as the original wrote it.
pub const PRESS_EXP: f64 = 0.190294957183635;
/// Standard sea-level pressure, used before the null estimate exists, Pa.
pub const P0_DEFAULT_PA: f64 = 101_325.0;
/// Magnetic declination / mounting offset added to the yaw (`IMU_TH_DEADLOCK_ANG`), rad.
pub const YAW_OFFSET_RAD: f64 = 0.17069;
/// Accelerometer norm fraction above which |a_x| means gimbal lock (9.72 / 9.81).
pub const DEADLOCK_ACC_NORM: f64 = 9.72 / 9.81;

type M3 = [[f64; 3]; 3];
type V3 = [f64; 3];

/// `m · v`, summed in the original's order.
fn mat_vec(m: &M3, v: &V3) -> V3 {
    let mut out = [0.0; 3];
    for (row, o) in m.iter().zip(out.iter_mut()) {
        let mut acc = 0.0;
        for (a, b) in row.iter().zip(v) {
            acc += a * b;
        }
        *o = acc;
    }
    out
}

/// Gain (T·K⁻¹) and offset of one three-axis sensor.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisCalib {
    /// Cross-axis matrix times inverse gain: SI units per count.
    pub tk_inv: M3,
    /// Offset, counts.
    pub offset_counts: V3,
}

impl AxisCalib {
    fn from_numbers(n: &[f64]) -> Self {
        AxisCalib {
            tk_inv: [[n[0], n[1], n[2]], [n[3], n[4], n[5]], [n[6], n[7], n[8]]],
            offset_counts: [n[9], n[10], n[11]],
        }
    }

    fn apply(&self, raw: &[f64; 3]) -> V3 {
        let centred = [
            raw[0] - self.offset_counts[0],
            raw[1] - self.offset_counts[1],
            raw[2] - self.offset_counts[2],
        ];
        mat_vec(&self.tk_inv, &centred)
    }
}

/// The calibration of spec 2.1 with the load-time derivations applied.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub acc: AxisCalib,
    /// Gyro gain and offset; the offset already includes `gyro_offset_extra`.
    pub gyro: AxisCalib,
    pub magn: AxisCalib,
    /// Accelerometer drift per °C, SI units (TK_inv_acc · [0, 0, acc_z_temp]).
    pub acc_t_off: V3,
    /// Accelerometer calibration temperature, °C.
    pub acc_t0_c: f64,
    /// Gyro drift per °C, rad/s (TK_inv_gyro · gyro_temp_coef).
    pub gyro_t_off: V3,
    /// Gyro calibration temperature, °C.
    pub gyro_t0_c: f64,
}

/// Why an `imu_calib.txt` was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibError {
    #[error(transparent)]
    Number(#[from] NumberError),
}

impl Calibration {
    /// Parses the text of a 45-number `imu_calib.txt`.
    pub fn parse(text: &str) -> Result<Calibration, CalibError> {
        let n = numfile::parse_exact(text, CALIB_NUMBERS)?;
        Ok(Self::from_numbers(&n))
    }

    /// Builds the model from the 45 numbers in file order.
    pub fn from_numbers(n: &[f64]) -> Calibration {
        let acc = AxisCalib::from_numbers(&n[0..12]);
        let mut gyro = AxisCalib::from_numbers(&n[12..24]);
        let magn = AxisCalib::from_numbers(&n[24..36]);
        let acc_z_temp = n[36];
        let acc_t0_c = n[37];
        let gyro_temp_coef = [n[38], n[39], n[40]];
        let gyro_offset_extra = [n[41], n[42], n[43]];
        let gyro_t0_c = n[44];
        for (b, extra) in gyro.offset_counts.iter_mut().zip(gyro_offset_extra) {
            *b += extra;
        }
        let acc_t_off = mat_vec(&acc.tk_inv, &[0.0, 0.0, acc_z_temp]);
        let gyro_t_off = mat_vec(&gyro.tk_inv, &gyro_temp_coef);
        Calibration {
            acc,
            gyro,
            magn,
            acc_t_off,
            acc_t0_c,
            gyro_t_off,
            gyro_t0_c,
        }
    }

    /// Inverse of the conversion for the simulator: the raw counts that read as the given values.
    pub fn counts_for(
        &self,
        acc_m_s2: &V3,
        temp_c: f64,
        gyro_rad_s: &V3,
        gyro_null_rad_s: &V3,
    ) -> (V3, V3) {
        let acc_target: V3 =
            std::array::from_fn(|i| acc_m_s2[i] + self.acc_t_off[i] * (temp_c - self.acc_t0_c));
        let gyro_target: V3 = std::array::from_fn(|i| {
            gyro_rad_s[i] + gyro_null_rad_s[i] + self.gyro_t_off[i] * (temp_c - self.gyro_t0_c)
        });
        let acc = solve3(&self.acc.tk_inv, &acc_target);
        let gyro = solve3(&self.gyro.tk_inv, &gyro_target);
        (
            std::array::from_fn(|i| acc[i] + self.acc.offset_counts[i]),
            std::array::from_fn(|i| gyro[i] + self.gyro.offset_counts[i]),
        )
    }
}

impl Calibration {
    /// Inverse of the magnetometer conversion: the counts that read as field `m`.
    pub fn magn_counts_for(&self, m: &V3) -> V3 {
        let c = solve3(&self.magn.tk_inv, m);
        std::array::from_fn(|i| c[i] + self.magn.offset_counts[i])
    }
}

/// Solves `m · x = v` by Cramer's rule (3×3, well conditioned calibration matrices).
fn solve3(m: &M3, v: &V3) -> V3 {
    let det = |a: &M3| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let d = det(m);
    std::array::from_fn(|col| {
        let mut c = *m;
        for row in 0..3 {
            c[row][col] = v[row];
        }
        det(&c) / d
    })
}

/// A converted IMU sample (spec 2.2 + 2.6): what the estimator consumes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuSample {
    /// Firmware period of the newest frame, µs.
    pub t_us: u32,
    pub acc_m_s2: V3,
    pub gyro_rad_s: V3,
    /// Calibrated magnetometer (arbitrary unit; only its direction matters).
    pub magn: V3,
    /// (ψ roll, φ pitch, θ yaw) from accelerometer + magnetometer, rad.
    pub euler_rad: V3,
    pub temp_c: f64,
    /// Barometric altitude above the start-up reference, m.
    pub alt_m: f64,
}

/// References set by the start-up null estimate (spec 2.4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NullReference {
    /// Converted gyro average at rest, subtracted from every later gyro reading, rad/s.
    pub gyro_null_rad_s: V3,
    /// Reference pressure for the altitude, Pa.
    pub p0_pa: f64,
}

impl Default for NullReference {
    /// Before calibration: no gyro null and the standard atmosphere.
    fn default() -> Self {
        NullReference {
            gyro_null_rad_s: [0.0; 3],
            p0_pa: P0_DEFAULT_PA,
        }
    }
}

/// The BMP085's measuring range (its datasheet: 300 to 1100 hPa), Pa. A reading outside it is
/// a failed sensor, not a pressure: 0 Pa would read as 44 km up.
pub const BARO_RANGE_PA: std::ops::RangeInclusive<f64> = 30_000.0..=110_000.0;

/// Barometric altitude (spec 2.2), m; not a number for a pressure outside the sensor's range,
/// so that the filter refuses the measurement instead of fusing it.
pub fn altitude_m(p_pa: f64, p0_pa: f64) -> f64 {
    if !BARO_RANGE_PA.contains(&p_pa) {
        return f64::NAN;
    }
    PRESS_K_M * (1.0 - math::pow(p_pa / p0_pa, PRESS_EXP))
}

/// Euler angles (ψ, φ, θ) from an acceleration and a calibrated magnetic field (spec 2.6).
pub fn euler_from_acc_magn(a: &V3, m: &V3) -> V3 {
    let norm = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    let (psi, phi) = if a[0].abs() < DEADLOCK_ACC_NORM * norm {
        (math::atan2(a[1], a[2]), -math::asin(a[0] / norm))
    } else if a[0] > 0.0 {
        (0.0, -PI_ORIGINAL / 2.0)
    } else {
        (0.0, PI_ORIGINAL / 2.0)
    };
    let (s_psi, c_psi) = math::sin_cos(psi);
    let (s_phi, c_phi) = math::sin_cos(phi);
    let rot = [
        [c_phi, s_phi * s_psi, c_psi * s_phi],
        [0.0, c_psi, -s_psi],
        [-s_phi, c_phi * s_psi, c_phi * c_psi],
    ];
    let mt = mat_vec(&rot, m);
    let theta = -math::atan2(mt[1], mt[0]) + YAW_OFFSET_RAD;
    [psi, phi, theta]
}

impl Calibration {
    /// Converts a raw (or FIR-filtered, already truncated) frame to SI units (spec 2.2).
    pub fn convert(&self, raw: &RawFrame, null: &NullReference) -> ImuSample {
        let f = |v: [i16; 3]| [f64::from(v[0]), f64::from(v[1]), f64::from(v[2])];
        let temp_c = f64::from(raw.temp_dc) / 10.0;
        let acc_lin = self.acc.apply(&f(raw.acc));
        let acc: V3 =
            std::array::from_fn(|i| acc_lin[i] - self.acc_t_off[i] * (temp_c - self.acc_t0_c));
        let gyro_lin = self.gyro.apply(&f(raw.gyro));
        let gyro: V3 = std::array::from_fn(|i| {
            gyro_lin[i] - self.gyro_t_off[i] * (temp_c - self.gyro_t0_c) - null.gyro_null_rad_s[i]
        });
        let magn = self.magn.apply(&f(raw.magn));
        ImuSample {
            t_us: raw.t_us,
            acc_m_s2: acc,
            gyro_rad_s: gyro,
            magn,
            euler_rad: euler_from_acc_magn(&acc, &magn),
            temp_c,
            alt_m: altitude_m(f64::from(raw.pres_pa), null.p0_pa),
        }
    }
}

/// How the start-up frames' pressures are averaged into the altitude's reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NullPressure {
    /// Integer division truncating toward zero, as the original's C did (its logs depend on
    /// it): the reference up to 1 Pa low (0.5 on average), against flight pressures the FIR
    /// truncates 0.45 Pa low on average, so the altitude is off by the difference (up to
    /// 0.08 m either way; 0.004 m low on average).
    #[default]
    Truncated,
    /// The exact mean, and the flight's pressures read from the FIR's sum before its
    /// truncation: both sides as they are. (Its truncation alone takes 0.45 Pa off on average,
    /// and the truncated reference's 0.5 Pa nearly cancelled it: an exact reference against
    /// truncated flight pressures read the altitude 0.04 m high.) The accelerometer, gyro and
    /// magnetometer nulls stay truncated either way: the frames they are compared with in
    /// flight are truncated too (the firmware's halving and the FIR filter), and a null without
    /// that bias would read as one.
    Exact,
}

/// Accumulates the start-up frames into the null (at-rest) estimate (spec 2.4).
#[derive(Debug, Clone, Default)]
pub struct NullAccumulator {
    frames: u32,
    acc: [i64; 3],
    gyro: [i64; 3],
    magn: [i64; 3],
    temp: i64,
    pres: u64,
}

/// The result of the null estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NullEstimate {
    /// The averaged frame, truncated as the original did.
    pub frame: RawFrame,
    /// Gyro null and pressure reference derived from it.
    pub reference: NullReference,
    /// The averaged frame converted with the reference applied (gyro ≈ 0, alt = 0): the
    /// sample that initialises the filter and the set point.
    pub sample: ImuSample,
}

impl NullAccumulator {
    pub fn push(&mut self, f: &RawFrame) {
        self.frames += 1;
        for i in 0..3 {
            self.acc[i] += i64::from(f.acc[i]);
            self.gyro[i] += i64::from(f.gyro[i]);
            self.magn[i] += i64::from(f.magn[i]);
        }
        self.temp += i64::from(f.temp_dc);
        self.pres += u64::from(f.pres_pa);
    }

    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// Averages the frames (integer division truncating toward zero, as C does; the pressure
    /// as `pressure` says) and derives the references. `None` before any frame was pushed.
    pub fn finish(&self, calib: &Calibration, pressure: NullPressure) -> Option<NullEstimate> {
        if self.frames == 0 {
            return None;
        }
        let n = i64::from(self.frames);
        // The quotient of i16 values lies in i16 range, so the narrowing cannot wrap.
        let avg = |s: [i64; 3]| [(s[0] / n) as i16, (s[1] / n) as i16, (s[2] / n) as i16];
        let frame = RawFrame {
            t_us: 0,
            acc: avg(self.acc),
            gyro: avg(self.gyro),
            magn: avg(self.magn),
            temp_dc: (self.temp / n) as i16,
            pres_pa: (self.pres / u64::from(self.frames)) as u32,
        };
        let before = calib.convert(&frame, &NullReference::default());
        let p0_pa = match pressure {
            NullPressure::Truncated => f64::from(frame.pres_pa),
            NullPressure::Exact => self.pres as f64 / f64::from(self.frames),
        };
        let reference = NullReference {
            gyro_null_rad_s: before.gyro_rad_s,
            p0_pa,
        };
        let mut sample = calib.convert(&frame, &reference);
        // The reference pressure is the average itself, so the altitude is zero by definition.
        sample.alt_m = 0.0;
        Some(NullEstimate {
            frame,
            reference,
            sample,
        })
    }
}

/// θ unwrapping (spec 3.8): brings a measured yaw within π of the reference yaw, using the
/// original's π and truncating division so the logged values match.
pub fn unwrap_theta(theta_m: f64, theta_ref: f64) -> f64 {
    let diff = theta_m - theta_ref;
    if diff.abs() < PI_ORIGINAL {
        return theta_m;
    }
    let turns = if diff > 0.0 {
        ((diff + PI_ORIGINAL) / (2.0 * PI_ORIGINAL)).trunc()
    } else {
        ((diff - PI_ORIGINAL) / (2.0 * PI_ORIGINAL)).trunc()
    };
    theta_m - turns * 2.0 * PI_ORIGINAL
}

#[cfg(test)]
mod tests {
    use super::*;

    fn identity_calib() -> Calibration {
        let mut n = vec![0.0; CALIB_NUMBERS];
        for block in 0..3 {
            n[block * 12] = 1.0;
            n[block * 12 + 4] = 1.0;
            n[block * 12 + 8] = 1.0;
        }
        Calibration::from_numbers(&n)
    }

    #[test]
    fn level_attitude_is_zero_roll_and_pitch() {
        let e = euler_from_acc_magn(&[0.0, 0.0, 9.81], &[1.0, 0.0, 0.0]);
        assert!(e[0].abs() < 1e-12 && e[1].abs() < 1e-12);
        assert!((e[2] - YAW_OFFSET_RAD).abs() < 1e-12);
        // Nose down 0.3 rad about y: a_x = -g sin(phi)... phi = -asin(ax/n).
        let phi = 0.3f64;
        let e = euler_from_acc_magn(
            &[-9.81 * phi.sin(), 0.0, 9.81 * phi.cos()],
            &[1.0, 0.0, 0.0],
        );
        assert!((e[1] - phi).abs() < 1e-12);
    }

    #[test]
    fn deadlock_branch() {
        let e = euler_from_acc_magn(&[9.81, 0.0, 0.1], &[1.0, 0.0, 0.0]);
        assert_eq!(e[0], 0.0);
        assert_eq!(e[1], -PI_ORIGINAL / 2.0);
    }

    #[test]
    fn unwrap_brings_theta_near_reference() {
        assert_eq!(unwrap_theta(1.0, 0.5), 1.0);
        let w = unwrap_theta(-3.0, 3.0);
        assert!((w - (-3.0 + 2.0 * PI_ORIGINAL)).abs() < 1e-12);
        let w = unwrap_theta(3.0, -3.0);
        assert!((w - (3.0 - 2.0 * PI_ORIGINAL)).abs() < 1e-12);
        // Several turns away.
        let w = unwrap_theta(0.1 + 6.0 * PI_ORIGINAL, 0.0);
        assert!((w - 0.1).abs() < 1e-9);
    }

    #[test]
    fn null_estimate_truncates_and_zeroes_gyro() {
        let c = identity_calib();
        let mut acc = NullAccumulator::default();
        for (g, p) in [(-3i16, 100_001u32), (-2, 100_002)] {
            acc.push(&RawFrame {
                gyro: [g, 0, 0],
                pres_pa: p,
                temp_dc: 250,
                ..RawFrame::default()
            });
        }
        let n = acc.finish(&c, NullPressure::Truncated).unwrap();
        // -5 / 2 truncates toward zero to -2; 200003 / 2 floors to 100001.
        assert_eq!(n.frame.gyro[0], -2);
        assert_eq!(n.frame.pres_pa, 100_001);
        assert_eq!(n.sample.gyro_rad_s, [0.0; 3]);
        assert_eq!(n.sample.alt_m, 0.0);
        assert_eq!(n.reference.p0_pa, 100_001.0);
        // The exact mean: the pressure's reference alone.
        let x = acc.finish(&c, NullPressure::Exact).unwrap();
        assert_eq!(x.reference.p0_pa, 100_001.5);
        assert_eq!(
            (x.frame, x.sample.gyro_rad_s),
            (n.frame, n.sample.gyro_rad_s)
        );
    }

    #[test]
    fn inverse_counts_convert_back() {
        let c = Calibration::parse(include_str!("../../../config/imu_calib.txt")).unwrap();
        let (acc, gyro) = c.counts_for(&[0.1, -0.2, 9.81], 30.0, &[0.01, 0.02, -0.03], &[0.0; 3]);
        let raw = RawFrame {
            acc: acc.map(|v| v.round() as i16),
            gyro: gyro.map(|v| v.round() as i16),
            temp_dc: 300,
            ..RawFrame::default()
        };
        let s = c.convert(&raw, &NullReference::default());
        assert!((s.acc_m_s2[2] - 9.81).abs() < 0.05, "{:?}", s.acc_m_s2);
        assert!((s.gyro_rad_s[1] - 0.02).abs() < 0.002, "{:?}", s.gyro_rad_s);
    }
}
