//! The simulator's faults (`--inject FAULT@T`): their names, parsing, the schedule both
//! ways of simulating read to know when each strikes, and what the faults of the IMU's wire
//! do to the bytes it sends ([`WireFaults`]), the same in both ways.

use crate::core::gps::SplitMix64;
use crate::core::imu::frame::{FRAME_LEN, RawFrame};

/// How long a stalled logger blocks (`log-stall`), µs.
pub const LOG_STALL_US: i64 = 500_000;

/// A fault injected at a simulated time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// The IMU stops sending frames.
    ImuStall,
    /// Every I2C write goes unacknowledged.
    EscNack,
    /// GPS fixes stop.
    GpsLoss,
    /// A logger's writes block for 500 ms.
    LogStall,
    /// Motor m0 loses 30 % of its thrust.
    ThrustLoss,
    /// The barometer reads 0 Pa (the altitude it gives is not finite).
    BaroFail,
    /// The gyro repeats its last reading.
    GyroStuck,
    /// Random bytes on the IMU's wire instead of frames.
    ImuGarbage,
    /// The simulated operator's link heartbeats stop.
    LinkLoss,
    /// A sideways push (`sim.gust_n` north, for `sim.gust_s`).
    Gust,
    /// The receiver's position jumps `sim.gps_glitch_m` north for `sim.gps_glitch_s`.
    GpsGlitch,
    /// The x gyro's bias steps by `sim.gyro_bias_step_rad_s`.
    GyroBias,
    /// The pilot's radio is lost (with `rc.protocol`): an SBUS receiver sends its failsafe
    /// flag, a CRSF receiver stops sending.
    RcLoss,
}

impl Fault {
    pub const NAMES: [(&'static str, Fault); 13] = [
        ("imu-stall", Fault::ImuStall),
        ("esc-nack", Fault::EscNack),
        ("gps-loss", Fault::GpsLoss),
        ("log-stall", Fault::LogStall),
        ("thrust-loss", Fault::ThrustLoss),
        ("baro-fail", Fault::BaroFail),
        ("gyro-stuck", Fault::GyroStuck),
        ("imu-garbage", Fault::ImuGarbage),
        ("link-loss", Fault::LinkLoss),
        ("gust", Fault::Gust),
        ("gps-glitch", Fault::GpsGlitch),
        ("gyro-bias", Fault::GyroBias),
        ("rc-loss", Fault::RcLoss),
    ];

    pub fn name(self) -> &'static str {
        Fault::NAMES
            .iter()
            .find(|(_, f)| *f == self)
            .map_or("?", |(n, _)| n)
    }
}

/// Parses `FAULT@T` (T in simulated seconds), e.g. `imu-stall@30`.
pub fn parse_injection(s: &str) -> Result<(Fault, f64), String> {
    let names = Fault::NAMES.map(|(n, _)| n).join(", ");
    let (name, at) = s
        .split_once('@')
        .ok_or_else(|| format!("{s:?}: expected FAULT@T, e.g. imu-stall@30 (faults: {names})"))?;
    let fault = Fault::NAMES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, f)| *f)
        .ok_or_else(|| format!("{name:?} is not a fault; one of {names}"))?;
    let t = crate::config::parse_fault_time_s(at).map_err(|e| format!("the time {e}"))?;
    Ok((fault, t))
}

/// When each injected fault strikes, µs of simulated time (the earliest, if given twice).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FaultSchedule {
    injected: Vec<(Fault, i64)>,
}

impl FaultSchedule {
    pub fn new(inject: &[(Fault, f64)]) -> Self {
        FaultSchedule {
            injected: inject
                .iter()
                .map(|&(f, at_s)| (f, (at_s * 1e6).round() as i64))
                .collect(),
        }
    }

    /// When `fault` strikes, if injected.
    pub fn at_us(&self, fault: Fault) -> Option<i64> {
        self.injected
            .iter()
            .filter(|(f, _)| *f == fault)
            .map(|(_, at)| *at)
            .min()
    }

    /// `fault` has struck by `t_us`.
    pub fn active(&self, fault: Fault, t_us: i64) -> bool {
        self.at_us(fault).is_some_and(|at| t_us >= at)
    }

    /// `fault` has struck by `t_us`, less than `lasts_s` ago.
    pub fn active_for(&self, fault: Fault, t_us: i64, lasts_s: f64) -> bool {
        self.at_us(fault)
            .is_some_and(|at| t_us >= at && ((t_us - at) as f64) < lasts_s * 1e6)
    }

    /// The err.log lines announcing the injections.
    pub fn notes(&self) -> impl Iterator<Item = String> + '_ {
        self.injected
            .iter()
            .map(|(f, at_us)| format!("fault injection: {} at {} s", f.name(), *at_us as f64 / 1e6))
    }
}

/// The faults of the IMU's wire and their state: the gyro reading a stuck gyro repeats, and
/// the generator of the garbage.
#[derive(Debug, Clone)]
pub struct WireFaults {
    stuck_gyro: Option<[i16; 3]>,
    rng: SplitMix64,
}

impl WireFaults {
    pub fn new(seed: u64) -> Self {
        WireFaults {
            stuck_gyro: None,
            rng: SplitMix64::new(seed ^ 0x1b0_9a4b),
        }
    }

    /// The bytes the IMU sends at `t_us` for `frame` (started by `start`), with the faults
    /// of `schedule` that have struck.
    pub fn bytes(
        &mut self,
        schedule: &FaultSchedule,
        t_us: i64,
        mut frame: RawFrame,
        start: u8,
    ) -> [u8; FRAME_LEN] {
        if schedule.active(Fault::ImuGarbage, t_us) {
            return std::array::from_fn(|_| (self.rng.next_u64() >> 56) as u8);
        }
        if schedule.active(Fault::BaroFail, t_us) {
            frame.pres_pa = 0;
        }
        if schedule.active(Fault::GyroStuck, t_us) {
            frame.gyro = *self.stuck_gyro.get_or_insert(frame.gyro);
        }
        frame.encode(start)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_schedules() {
        assert_eq!(parse_injection("imu-stall@30"), Ok((Fault::ImuStall, 30.0)));
        assert!(parse_injection("imu-stall").is_err());
        assert!(parse_injection("bogus@1").is_err());
        for bad_time in ["-1", "nan", "inf", "1e9", "soon"] {
            let err = parse_injection(&format!("esc-nack@{bad_time}"));
            assert!(err.is_err_and(|e| e.contains(bad_time)), "{bad_time}");
        }
        assert_eq!(parse_injection("esc-nack@0"), Ok((Fault::EscNack, 0.0)));
        let s = FaultSchedule::new(&[(Fault::EscNack, 2.0), (Fault::EscNack, 1.5)]);
        assert_eq!(s.at_us(Fault::EscNack), Some(1_500_000));
        assert!(!s.active(Fault::EscNack, 1_499_999));
        assert!(s.active(Fault::EscNack, 1_500_000));
        assert!(!s.active(Fault::ImuStall, i64::MAX));
    }

    #[test]
    fn wire_faults_change_the_bytes_from_their_time_on() {
        let s = FaultSchedule::new(&[
            (Fault::BaroFail, 1.0),
            (Fault::GyroStuck, 2.0),
            (Fault::ImuGarbage, 3.0),
        ]);
        let mut w = WireFaults::new(1);
        let f = |g: i16| RawFrame {
            t_us: 10_000,
            acc: [1, 2, 3],
            gyro: [g, g, g],
            magn: [4, 5, 6],
            temp_dc: 300,
            pres_pa: 101_000,
        };
        assert_eq!(w.bytes(&s, 0, f(7), b'C'), f(7).encode(b'C'));
        let mut no_baro = f(7);
        no_baro.pres_pa = 0;
        assert_eq!(w.bytes(&s, 1_000_000, f(7), b'C'), no_baro.encode(b'C'));
        let stuck = w.bytes(&s, 2_000_000, f(8), b'C');
        assert_eq!(
            w.bytes(&s, 2_010_000, f(9), b'C'),
            stuck,
            "the gyro repeats"
        );
        let garbage = w.bytes(&s, 3_000_000, f(9), b'C');
        assert_ne!(garbage, w.bytes(&s, 3_010_000, f(9), b'C'));
    }
}
