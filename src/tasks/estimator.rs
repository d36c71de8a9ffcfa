//! Estimator task: the measurement front end and the EKF, and the start-up sequence.
//!
//! In: stamped frames from the IMU reader; the controller's feedback (the EKF input for the
//! next step, the mass, the last command time); the ESC writer's phase.
//! Out: estimates to the controller; `imu_raw`, `kalman_in`, `x_hat` and `gps` records.
//! Rate: one Kalman step per frame once calibrated. Ends: when frames stop, on start-up
//! failure, or on cancel.
//!
//! Start-up: settle (stable sampling period, motors off) → ESC start-up ramp (the writer runs
//! it; frames keep filling the FIR) → calibration (the motors idle, as in the original) → the
//! flight ramp and run (the controller's first 100 steps ramp the motors up).

use crate::core::flight::{Estimate, EstimatorCore, GpsFeed};
use crate::core::imu::startup::FrontEndEvent;
use crate::logs::{ImuRawRecord, KalmanInRecord};
use crate::tasks::esc_writer::{EscMailbox, EscPhase, EscStatus};
use crate::tasks::gps_client::LiveFix;
use crate::tasks::imu_reader::StampedFrame;
use crate::tasks::logger::{LogHub, Record};
use crate::tasks::watchdog::{Event, Heartbeats};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// What the controller tells the estimator after each step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Feedback {
    /// The step this feedback follows (0 before the first).
    pub step: u32,
    /// EKF input for step `step + 1` (ERRATA 6).
    pub u_next: [f64; 4],
    pub mass_kg: f64,
    /// Time of the command of `step`, µs since start.
    pub t_cmd_us: Option<i64>,
}

/// An estimate on its way to the controller.
#[derive(Debug, Clone)]
pub struct EstimateMsg {
    pub est: Estimate,
    /// When the frame arrived (for the frame → ESC write latency).
    pub frame_at: Instant,
}

/// After this long without the previous step's feedback the wait is counted as late (it still
/// waits: the EKF input must be the previous command, and a stuck controller is the
/// watchdog's to catch as a missed deadline).
const FEEDBACK_LATE: Duration = Duration::from_millis(5);

/// Counters of the estimator.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EstimatorReport {
    pub frames: u64,
    pub steps: u64,
    pub late_feedback: u64,
    pub ekf_errors: u64,
    pub gps_updates: u64,
}

pub struct EstimatorTask {
    pub core: EstimatorCore,
    pub gps: GpsFeed,
    /// Live fixes (gps.mode = gpsd).
    pub gps_live: Option<watch::Receiver<Option<LiveFix>>>,
    pub frames: mpsc::Receiver<StampedFrame>,
    pub feedback: watch::Receiver<Feedback>,
    pub estimates: mpsc::Sender<EstimateMsg>,
    pub esc: Arc<EscMailbox>,
    pub esc_status: Arc<EscStatus>,
    pub logs: LogHub,
    pub beats: Arc<Heartbeats>,
    pub cancel: CancellationToken,
}

impl EstimatorTask {
    pub async fn run(mut self) -> anyhow::Result<EstimatorReport> {
        let mut rep = EstimatorReport::default();
        let mut prev_stamp_us: Option<i64> = None;
        let mut esc_started = false;
        let mut offered: Option<LiveFix> = None;
        loop {
            let f = tokio::select! {
                _ = self.cancel.cancelled() => break,
                f = self.frames.recv() => match f {
                    Some(f) => f,
                    None => break,
                },
            };
            rep.frames += 1;
            let raw = Record::ImuRaw(ImuRawRecord {
                t_main_us: f.stamp_us,
                t_frame_us: f.stamp_us,
                frame: f.frame,
            });
            let sample = match self.core.on_frame(&f.frame, f.stamp_us) {
                FrontEndEvent::Settling { .. } => continue,
                FrontEndEvent::Holding => {
                    if !esc_started {
                        esc_started = true;
                        self.logs
                            .err("IMU sampling period stable; ESC start-up ramp");
                        tracing::info!("IMU sampling period stable; ESC start-up ramp");
                        self.esc.start();
                    }
                    match self.esc_status.phase() {
                        EscPhase::Running => {
                            self.logs.err("ESC ramp done; IMU calibration");
                            tracing::info!("ESC ramp done; IMU calibration");
                            self.core.begin_calibration();
                        }
                        EscPhase::Stopped => anyhow::bail!(
                            "the ESCs stopped during their start-up ramp: {}",
                            self.esc_status.stop_reason().unwrap_or_default()
                        ),
                        EscPhase::Disabled | EscPhase::Ramping => {}
                    }
                    continue;
                }
                FrontEndEvent::Calibrating { .. } => {
                    self.logs.log(raw);
                    continue;
                }
                FrontEndEvent::Failed(e) => anyhow::bail!("IMU start-up failed: {e}"),
                FrontEndEvent::Calibrated(null) => {
                    self.logs.log(raw);
                    self.logs.err(format!(
                        "IMU calibration completed: acc {:?} m/s2, euler {:?} rad, temp {} C",
                        null.sample.acc_m_s2, null.sample.euler_rad, null.sample.temp_c
                    ));
                    tracing::info!("IMU calibrated; flight ramp");
                    null.sample
                }
                FrontEndEvent::Sample(s) => {
                    self.logs.log(raw);
                    s
                }
            };
            let step = self.core.steps() + 1;
            // The feedback of the previous step: the EKF input and the command time.
            let Some(fb) = self.wait_feedback(step - 1, &mut rep).await else {
                break;
            };
            if let Some(t_cmd) = fb.t_cmd_us
                && self.gps.after_command(t_cmd)
            {
                self.logs.log(Record::Gps(t_cmd));
            }
            if let Some(rx) = self.gps_live.as_mut()
                && rx.has_changed().unwrap_or(false)
                && let Some(live) = *rx.borrow_and_update()
            {
                self.gps.offer_live(live.sample);
                offered = Some(live);
            }
            let gps = self.gps.for_step(f.stamp_us);
            if gps.is_some()
                && let Some(live) = offered.take()
            {
                // Logged with a time the replay fuses in this same step.
                let t = prev_stamp_us.unwrap_or(f.stamp_us - 1);
                self.logs.log(Record::GpsFix(t, live));
            }
            let Some(est) = self
                .core
                .step(sample, f.stamp_us, fb.u_next, fb.mass_kg, gps)
            else {
                continue;
            };
            rep.steps += 1;
            rep.gps_updates += u64::from(est.gps_used);
            self.beats.report(Event::Estimate {
                step_us: est.t_us,
                temp_c: est.sample.temp_c,
                psi_rad: est.x[crate::core::ekf::idx::PSI],
                phi_rad: est.x[crate::core::ekf::idx::PHI],
            });
            if let Some(e) = est.ekf_error {
                rep.ekf_errors += 1;
                tracing::warn!(step, "{e}");
            }
            let dt_col = prev_stamp_us.map_or(0, |p| f.stamp_us - p);
            prev_stamp_us = Some(f.stamp_us);
            self.logs.log(Record::KalmanIn(KalmanInRecord::from_sample(
                est.t_us,
                dt_col,
                &est.sample,
            )));
            self.logs.log(Record::XHat(est.x.into()));
            let msg = EstimateMsg {
                est,
                frame_at: f.at,
            };
            if self.estimates.send(msg).await.is_err() {
                break;
            }
        }
        Ok(rep)
    }

    /// The controller's feedback for `step`; `None` when the controller is gone or on cancel.
    async fn wait_feedback(&mut self, step: u32, rep: &mut EstimatorReport) -> Option<Feedback> {
        let ready = |fb: &Feedback| fb.step >= step;
        if !ready(&self.feedback.borrow()) {
            let t0 = Instant::now();
            let cancel = self.cancel.clone();
            let got = tokio::select! {
                _ = cancel.cancelled() => false,
                r = self.feedback.wait_for(|fb| ready(fb)) => r.is_ok(),
            };
            if t0.elapsed() > FEEDBACK_LATE {
                rep.late_feedback += 1;
            }
            if !got {
                return None;
            }
        }
        Some(*self.feedback.borrow())
    }
}
