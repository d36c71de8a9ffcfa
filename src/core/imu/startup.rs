//! The start-up phases before flight: wait for a stable sampling period, then average the
//! null (at-rest) sample, while the FIR window fills over every frame.
//!
//! Spec section 8.3 steps 3–6 and 2.4. Time enters only as the frame stamps the caller passes
//! (µs, monotonic), so the same sequence gives the same result in flight, simulation and replay.

use super::calib::{
    Calibration, ImuSample, NullAccumulator, NullEstimate, NullPressure, altitude_m,
};
use super::filter::Fir;
use super::frame::RawFrame;

/// Parameters of the start-up phases (from the `imu.*` configuration keys).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StartupParams {
    /// Consecutive in-range intervals needed before calibrating (the original: 50).
    pub settle_frames: u32,
    /// Frames after which settling gives up (the original: 60).
    pub settle_max_frames: u32,
    /// Time after which settling gives up, µs (the original: 10 s).
    pub settle_timeout_us: i64,
    /// Accepted frame interval, µs (the original: 8000 ..= 12000).
    pub period_min_us: i64,
    pub period_max_us: i64,
    /// Frames averaged into the null sample (the original: 512).
    pub calib_frames: u32,
    /// How their pressures are averaged (the original: truncated).
    pub null_pressure: NullPressure,
}

impl StartupParams {
    /// The original's values (spec 1.5, 2.4, 8.3).
    pub const ORIGINAL: StartupParams = StartupParams {
        settle_frames: 50,
        settle_max_frames: 60,
        settle_timeout_us: 10_000_000,
        period_min_us: 8_000,
        period_max_us: 12_000,
        calib_frames: 512,
        null_pressure: NullPressure::Truncated,
    };
}

/// When the IMU's null sample is taken (`imu.calibrate`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CalibrateWhen {
    /// At rest, motors off, as soon as the sampling period is stable: the estimator runs from
    /// then on, disarmed (telemetry, the `estimator` pre-arm check), and arming starts the
    /// ESCs under a running estimate.
    BeforeArm,
    /// After `arm` and the ESCs' start-up ramp, with the motors idling (the original's order:
    /// the null sample then holds the motors' vibration and magnetic field).
    #[default]
    AfterArm,
}

impl CalibrateWhen {
    /// The configuration's word for it.
    pub fn name(self) -> &'static str {
        match self {
            CalibrateWhen::BeforeArm => "before-arm",
            CalibrateWhen::AfterArm => "after-arm",
        }
    }
}

/// Why start-up failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StartupError {
    #[error(
        "IMU sampling period not stable after {frames} frames ({good} good intervals in a row, {needed} needed)"
    )]
    TooManyFrames { frames: u32, good: u32, needed: u32 },
    #[error("IMU sampling period not stable after {elapsed_us} µs")]
    Timeout { elapsed_us: i64 },
}

/// What one frame did to the start-up.
#[derive(Debug, Clone, PartialEq)]
pub enum FrontEndEvent {
    /// Still waiting for a stable period; `good` consecutive intervals so far.
    Settling { good: u32 },
    /// Frame added to the null estimate (`frames` of the total so far).
    Calibrating { frames: u32 },
    /// The null estimate is complete (this frame was its last).
    Calibrated(NullEstimate),
    /// Settled and holding until calibration is started.
    Holding,
    /// A filtered, converted sample for the estimator.
    Sample(ImuSample),
    /// Start-up failed; motors must stay off.
    Failed(StartupError),
}

#[derive(Debug, Clone)]
enum Phase {
    Settling {
        first_us: i64,
        frames: u32,
        good: u32,
    },
    /// Settled; waiting for `begin_calibration` (frames still fill the FIR).
    Holding,
    Calibrating(NullAccumulator),
    Running(NullEstimate),
    Failed(StartupError),
}

/// The measurement front end: start-up phases, FIR, conversion.
#[derive(Debug, Clone)]
pub struct ImuFrontEnd {
    params: StartupParams,
    calib: Calibration,
    fir: Fir,
    phase: Option<Phase>,
    last_stamp_us: Option<i64>,
    hold_after_settle: bool,
}

impl ImuFrontEnd {
    /// `skip_settle` starts directly with calibration: replay uses it because the original's
    /// `imu_raw.log` does not hold the settling frames (spec 1.6).
    pub fn new(params: StartupParams, calib: Calibration, skip_settle: bool) -> Self {
        let phase = if skip_settle || params.settle_frames == 0 {
            Some(Phase::Calibrating(NullAccumulator::default()))
        } else {
            None
        };
        ImuFrontEnd {
            params,
            calib,
            fir: Fir::new(),
            phase,
            last_stamp_us: None,
            hold_after_settle: false,
        }
    }

    /// After settling, hold until [`ImuFrontEnd::begin_calibration`] instead of calibrating.
    pub fn hold_after_settle(mut self) -> Self {
        self.hold_after_settle = true;
        self
    }

    /// Starts the calibration when holding (and lets it start at once if still settling).
    pub fn begin_calibration(&mut self) {
        self.hold_after_settle = false;
        if matches!(self.phase, Some(Phase::Holding)) {
            self.phase = Some(Phase::Calibrating(NullAccumulator::default()));
        }
    }

    /// Takes the null sample again from the next frame (the FIR window stays full).
    pub fn restart_calibration(&mut self) {
        self.hold_after_settle = false;
        if !matches!(self.phase, Some(Phase::Failed(_))) {
            self.phase = Some(Phase::Calibrating(NullAccumulator::default()));
        }
    }

    pub fn calibration(&self) -> &Calibration {
        &self.calib
    }

    /// The null estimate once calibration finished.
    pub fn null_estimate(&self) -> Option<&NullEstimate> {
        match &self.phase {
            Some(Phase::Running(n)) => Some(n),
            _ => None,
        }
    }

    /// The FIR's frame in SI units. With the exact reference the altitude is read from the
    /// FIR's pressure before its truncation, `p_pa`, too: truncating the flight's side alone
    /// would read the altitude 0.04 m high on average, against the reference's exact mean.
    fn convert(&self, filtered: &RawFrame, p_pa: f64, null: &NullEstimate) -> ImuSample {
        let mut sample = self.calib.convert(filtered, &null.reference);
        if self.params.null_pressure == NullPressure::Exact {
            sample.alt_m = altitude_m(p_pa, null.reference.p0_pa);
        }
        sample
    }

    /// Feeds one frame stamped at `stamp_us` (when its last byte was decoded).
    pub fn on_frame(&mut self, frame: &RawFrame, stamp_us: i64) -> FrontEndEvent {
        let interval_us = self.last_stamp_us.map(|last| stamp_us - last);
        self.last_stamp_us = Some(stamp_us);
        self.fir.push(*frame);
        let p = self.params;
        let phase = self.phase.take().unwrap_or(Phase::Settling {
            first_us: stamp_us,
            frames: 0,
            good: 0,
        });
        let (next, event) = match phase {
            Phase::Settling {
                first_us,
                frames,
                good,
            } => {
                let frames = frames + 1;
                let good = match interval_us {
                    Some(dt) if (p.period_min_us..=p.period_max_us).contains(&dt) => good + 1,
                    _ => 0,
                };
                if good >= p.settle_frames {
                    let next = if self.hold_after_settle {
                        Phase::Holding
                    } else {
                        Phase::Calibrating(NullAccumulator::default())
                    };
                    (next, FrontEndEvent::Settling { good })
                } else if frames > p.settle_max_frames {
                    let e = StartupError::TooManyFrames {
                        frames,
                        good,
                        needed: p.settle_frames,
                    };
                    (Phase::Failed(e.clone()), FrontEndEvent::Failed(e))
                } else if stamp_us - first_us > p.settle_timeout_us {
                    let e = StartupError::Timeout {
                        elapsed_us: stamp_us - first_us,
                    };
                    (Phase::Failed(e.clone()), FrontEndEvent::Failed(e))
                } else {
                    (
                        Phase::Settling {
                            first_us,
                            frames,
                            good,
                        },
                        FrontEndEvent::Settling { good },
                    )
                }
            }
            Phase::Holding => (Phase::Holding, FrontEndEvent::Holding),
            Phase::Calibrating(mut acc) => {
                acc.push(frame);
                let frames = acc.frames();
                if frames >= p.calib_frames {
                    match acc.finish(&self.calib, p.null_pressure) {
                        Some(null) => (Phase::Running(null), FrontEndEvent::Calibrated(null)),
                        // Unreachable with calib_frames ≥ 1 (validated at load); stay safe anyway.
                        None => (
                            Phase::Calibrating(acc),
                            FrontEndEvent::Calibrating { frames },
                        ),
                    }
                } else {
                    (
                        Phase::Calibrating(acc),
                        FrontEndEvent::Calibrating { frames },
                    )
                }
            }
            Phase::Running(null) => {
                let event = match self.fir.filtered() {
                    Some((frame, p_pa)) => FrontEndEvent::Sample(self.convert(&frame, p_pa, &null)),
                    // Only when calib_frames < 6: the window is not full yet.
                    None => FrontEndEvent::Calibrating {
                        frames: self.params.calib_frames,
                    },
                };
                (Phase::Running(null), event)
            }
            Phase::Failed(e) => (Phase::Failed(e.clone()), FrontEndEvent::Failed(e)),
        };
        self.phase = Some(next);
        event
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn calib() -> Calibration {
        let mut n = vec![0.0; super::super::calib::CALIB_NUMBERS];
        for block in 0..3 {
            n[block * 12] = 0.01;
            n[block * 12 + 4] = 0.01;
            n[block * 12 + 8] = 0.01;
        }
        Calibration::from_numbers(&n)
    }

    fn frame(g: i16) -> RawFrame {
        RawFrame {
            t_us: 10_000,
            acc: [0, 0, 981],
            gyro: [g, 0, 0],
            magn: [100, 0, 0],
            temp_dc: 250,
            pres_pa: 101_000,
        }
    }

    fn params() -> StartupParams {
        StartupParams {
            settle_frames: 3,
            settle_max_frames: 6,
            calib_frames: 8,
            ..StartupParams::ORIGINAL
        }
    }

    #[test]
    fn settles_then_calibrates_then_samples() {
        let mut fe = ImuFrontEnd::new(params(), calib(), false);
        let mut t = 0;
        let mut events = vec![];
        for _ in 0..4 {
            events.push(fe.on_frame(&frame(5), t));
            t += 10_000;
        }
        assert_eq!(events[3], FrontEndEvent::Settling { good: 3 });
        for i in 0..8 {
            let e = fe.on_frame(&frame(5), t);
            t += 10_000;
            if i < 7 {
                assert_eq!(e, FrontEndEvent::Calibrating { frames: i + 1 });
            } else {
                let FrontEndEvent::Calibrated(null) = e else {
                    panic!("{e:?}")
                };
                assert_eq!(null.sample.gyro_rad_s, [0.0; 3]);
            }
        }
        let FrontEndEvent::Sample(s) = fe.on_frame(&frame(105), t) else {
            panic!()
        };
        // 0.2 of the new frame's extra 100 counts at 0.01 rad/s per count.
        assert!((s.gyro_rad_s[0] - 0.2).abs() < 1e-12, "{s:?}");
    }

    /// The altitude the front end reads, calibrated and then flown on frames whose pressures
    /// alternate by 1 Pa (their mean half a pascal between), with `pressure`.
    fn altitude_on_alternating_pressures(pressure: NullPressure) -> f64 {
        let p = StartupParams {
            null_pressure: pressure,
            ..params()
        };
        let mut fe = ImuFrontEnd::new(p, calib(), false);
        let at = |i: i64| RawFrame {
            pres_pa: 101_000 + (i % 2) as u32,
            ..frame(5)
        };
        let mut last = FrontEndEvent::Settling { good: 0 };
        for i in 0..20 {
            last = fe.on_frame(&at(i), i * 10_000);
        }
        let FrontEndEvent::Sample(s) = last else {
            panic!("{last:?}")
        };
        s.alt_m
    }

    #[test]
    fn the_exact_reference_reads_the_filtered_pressure_untruncated() {
        // The window sums to 101000.5 Pa, the reference's exact mean: no altitude at all.
        let exact = altitude_on_alternating_pressures(NullPressure::Exact);
        assert!(exact.abs() < 1e-9, "{exact}");
        // The original's: the reference truncated to 101000 and the window's sum too.
        let truncated = altitude_on_alternating_pressures(NullPressure::Truncated);
        assert!(truncated.abs() < 1e-9, "{truncated}");
    }

    #[test]
    fn holds_after_settling_until_told() {
        let mut fe = ImuFrontEnd::new(params(), calib(), false).hold_after_settle();
        let mut t = 0;
        for _ in 0..4 {
            fe.on_frame(&frame(5), t);
            t += 10_000;
        }
        for _ in 0..20 {
            assert_eq!(fe.on_frame(&frame(5), t), FrontEndEvent::Holding);
            t += 10_000;
        }
        fe.begin_calibration();
        assert_eq!(
            fe.on_frame(&frame(5), t),
            FrontEndEvent::Calibrating { frames: 1 }
        );
    }

    #[test]
    fn unstable_period_fails_after_max_frames() {
        let mut fe = ImuFrontEnd::new(params(), calib(), false);
        let mut last = FrontEndEvent::Settling { good: 0 };
        for i in 0..7 {
            // 20 ms apart: never in range.
            last = fe.on_frame(&frame(0), i * 20_000);
        }
        assert!(matches!(
            last,
            FrontEndEvent::Failed(StartupError::TooManyFrames { frames: 7, .. })
        ));
        // Stays failed.
        assert!(matches!(
            fe.on_frame(&frame(0), 200_000),
            FrontEndEvent::Failed(_)
        ));
    }

    #[test]
    fn timeout() {
        let p = StartupParams {
            settle_timeout_us: 25_000,
            ..params()
        };
        let mut fe = ImuFrontEnd::new(p, calib(), false);
        fe.on_frame(&frame(0), 0);
        fe.on_frame(&frame(0), 7_000);
        let e = fe.on_frame(&frame(0), 30_000);
        assert!(matches!(
            e,
            FrontEndEvent::Failed(StartupError::Timeout { .. })
        ));
    }
}
