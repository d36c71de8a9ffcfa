//! The simulator's faults (`--inject FAULT@T`): their names, parsing, and the schedule both
//! ways of simulating read to know when each strikes.

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
}

impl Fault {
    pub const NAMES: [(&'static str, Fault); 5] = [
        ("imu-stall", Fault::ImuStall),
        ("esc-nack", Fault::EscNack),
        ("gps-loss", Fault::GpsLoss),
        ("log-stall", Fault::LogStall),
        ("thrust-loss", Fault::ThrustLoss),
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

    /// The err.log lines announcing the injections.
    pub fn notes(&self) -> impl Iterator<Item = String> + '_ {
        self.injected
            .iter()
            .map(|(f, at_us)| format!("fault injection: {} at {} s", f.name(), *at_us as f64 / 1e6))
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
}
