//! The control path of a `fly` run on its own OS thread: a current-thread runtime (SCHED_FIFO
//! when permitted) running the IMU reader, the estimator task and the controller task, which
//! carry messages into the flight sequence's two sides (`core::flight::sequence`).

use super::{FlyOptions, RunHandles};
use crate::app::flight::live_sides;
use crate::config::{GpsMode, Profile};
use crate::core::commander::OperatorInput;
use crate::core::gps::LiveFix;
use crate::tasks::controller::{ControllerReport, ControllerTask, Live};
use crate::tasks::esc_writer::HaltOnPanic;
use crate::tasks::estimator::{EstimatorReport, EstimatorTask};
use crate::tasks::prearm::PreArm;
use crate::tasks::{CONTROL_PRIORITY, Cpu, TaskOutputs};
use crate::tasks::{gps_client, imu_reader};
use anyhow::Context;
use std::thread::JoinHandle;
use tokio::sync::{mpsc, watch};
use tracing::Instrument;

/// What the control path reads from and publishes to, beyond the shared handles.
pub(super) struct Inputs {
    pub imu: Box<dyn super::ImuIo>,
    /// Live fixes (gps.mode = gpsd), from [`live_fixes`].
    pub gps_live: Option<watch::Receiver<Option<LiveFix>>>,
    pub operator: mpsc::Receiver<OperatorInput>,
    pub live: watch::Sender<Option<Live>>,
    /// Why the run folder cannot be written, as last probed (a pre-arm check).
    pub log_problem: watch::Receiver<Option<String>>,
}

#[derive(Debug, Clone, Default)]
pub(super) struct Reports {
    pub estimator: EstimatorReport,
    pub controller: ControllerReport,
}

/// Spawns the control thread; whatever ends it (an error, a panic) ends the run.
pub(super) fn spawn(
    profile: &Profile,
    inputs: Inputs,
    opts: &FlyOptions,
    h: &RunHandles,
) -> anyhow::Result<JoinHandle<anyhow::Result<Reports>>> {
    let gps_live = inputs.gps_live.clone();
    let (estimator, controller) = live_sides(profile);
    let prearm = PreArm {
        log_problem: inputs.log_problem.clone(),
        realtime_waived: opts.realtime_waived,
        gps_required: profile.config.gps.mode == GpsMode::Gpsd,
        gps_max_eph_m: profile.config.commander.gps_max_eph_m,
        gps_timeout_us: (profile.config.control.gps_hold_timeout_s * 1e6).round() as i64,
        addresses: profile.motor_map().addresses,
        verdict: h.prearm_verdict.clone(),
    };
    let h = h.clone();
    let input_expiry_s = profile.config.commander.input_expiry_s;
    let (realtime, delay, panic_at_step, auto_arm) = (
        opts.realtime,
        opts.control_delay,
        opts.control_panic_at,
        opts.arm_at_start,
    );
    crate::tasks::spawn_thread(
        "control",
        realtime,
        CONTROL_PRIORITY,
        Cpu::First,
        move || {
            let _end_run = h.cancel.clone().drop_guard();
            let _halt = HaltOnPanic {
                mailbox: h.mailbox.clone(),
                cancel: h.cancel.clone(),
            };
            let rt = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .context("cannot build the control runtime")?;
            let out = TaskOutputs {
                logs: h.logs.clone(),
                beats: h.beats.clone(),
                notices: h.notices.clone(),
            };
            let (fb_tx, fb_rx) = watch::channel(controller.first_feedback());
            let (est_tx, est_rx) = mpsc::channel(1);
            let controller = ControllerTask {
                side: controller,
                estimates: est_rx,
                feedback: fb_tx,
                esc: h.mailbox.clone(),
                out: out.clone(),
                cancel: h.cancel.clone(),
                delay,
                panic_at_step,
                live: inputs.live,
            };
            rt.block_on(async move {
                let (frame_tx, frame_rx) = mpsc::channel(8);
                let reader = imu_reader::run(
                    inputs.imu,
                    h.beats.clone(),
                    frame_tx,
                    h.imu_stats.clone(),
                    h.cancel.clone(),
                );
                let reader = tokio::spawn(reader.instrument(tracing::info_span!("imu_reader")));
                let controller = tokio::spawn(
                    controller
                        .run()
                        .instrument(tracing::info_span!("controller")),
                );
                let estimator = EstimatorTask {
                    side: estimator,
                    gps_live,
                    frames: frame_rx,
                    feedback: fb_rx,
                    estimates: est_tx,
                    esc: h.mailbox.clone(),
                    esc_status: h.esc_status.clone(),
                    out,
                    cancel: h.cancel.clone(),
                    operator: inputs.operator,
                    prearm,
                    auto_arm,
                    watchdog: h.wd_status.clone(),
                    pending_fix: None,
                    held: Default::default(),
                    input_expiry: std::time::Duration::from_secs_f64(input_expiry_s),
                    next_prearm_us: 0,
                }
                .run()
                .instrument(tracing::info_span!("estimator"))
                .await;
                // The estimator ends when frames stop, on an abort or on cancel: end the run.
                h.cancel.cancel();
                if let Ok(Err(e)) = reader.await {
                    tracing::warn!("IMU read error: {e}");
                }
                // A panic in the controller task already halted the motors (`HaltOnPanic`).
                let controller = controller.await.map_err(|e| {
                    let why = e.try_into_panic().map_or_else(
                        |e| e.to_string(),
                        |p| crate::tasks::panic_message(p.as_ref()),
                    );
                    anyhow::anyhow!("the controller task panicked: {why}")
                });
                Ok(Reports {
                    estimator: estimator?,
                    controller: controller?,
                })
            })
        },
    )
    .context("cannot start the control thread")
}

/// gps.mode = "gpsd": the caller's fixes (the simulator) or a gpsd client on the main runtime,
/// so the control path never waits on gpsd. The gps.log header says the log holds fixes.
pub(super) fn live_fixes(
    profile: &Profile,
    given: Option<watch::Receiver<Option<LiveFix>>>,
    h: &RunHandles,
) -> Option<watch::Receiver<Option<LiveFix>>> {
    if profile.config.gps.mode != GpsMode::Gpsd {
        return None;
    }
    Some(given.unwrap_or_else(|| {
        let (tx, rx) = watch::channel(None);
        tokio::spawn(gps_client::run(
            profile.config.gps.server.clone(),
            h.beats.start(),
            tx,
            h.gps_stats.clone(),
            h.cancel.clone(),
        ));
        rx
    }))
}
