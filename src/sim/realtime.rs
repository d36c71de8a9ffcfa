//! `uquad sim --realtime`: fly's own tasks, threads and channels against the simulated edges,
//! paced by the wall clock. A simulator thread steps the physics at `sim.physics_hz`, sends the
//! IMU's frames through an in-memory pipe into fly's IMU reader, and the ESC writer's I2C
//! writes reach the simulated ESCs through the bus trait.

use crate::app::fly::{self, Edges, FlyOptions};
use crate::config::Profile;
use crate::sim::esc::{EscModel, SimBus};
use crate::sim::run::{HoverAcc, HoverStats, SimOptions, SimSummary};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::io::AsyncWriteExt;
use tokio_util::sync::CancellationToken;

pub async fn run(profile: &Profile, opts: &SimOptions) -> anyhow::Result<SimSummary> {
    let cfg = &profile.config;
    let sc = cfg.sim.clone();
    let duration = Duration::from_secs_f64(opts.duration_s.unwrap_or(sc.duration_s));
    let seed = opts.seed.unwrap_or(sc.seed);
    let start = Instant::now();
    let model = Arc::new(Mutex::new(EscModel::new(profile.motor_map())));
    let (host, mut imu_end) = tokio::io::duplex(64 * 1024);
    let stop = Arc::new(AtomicBool::new(false));
    let hover = Arc::new(Mutex::new(HoverStats::default()));
    let rt = tokio::runtime::Handle::current();
    let fault_at = |f: crate::sim::run::Fault| {
        opts.inject
            .iter()
            .filter(|(g, _)| *g == f)
            .map(|(_, at)| (at * 1e6).round() as i64)
            .min()
    };
    // gps.mode = "gpsd": a fix of the true position each simulated second, through the
    // channel fly's gpsd client would publish on.
    let (gps_tx, gps_rx) = tokio::sync::watch::channel(None);
    let gps_live = cfg.gps.mode == crate::config::GpsMode::Gpsd;
    let imu_stall_at = fault_at(crate::sim::run::Fault::ImuStall);
    let esc_nack_at = fault_at(crate::sim::run::Fault::EscNack);
    let sim_thread = {
        let model = model.clone();
        let stop = stop.clone();
        let profile = profile.clone();
        let hover_z = cfg.control.hover_z_m;
        let hover = hover.clone();
        let progress = opts.progress;
        std::thread::Builder::new()
            .name("sim".into())
            .spawn(move || {
                crate::tasks::raise_priority("sim", 60);
                let (mut plant, mut imu) = crate::sim::vehicle(&profile, seed);
                let step_us = 1_000_000 / i64::from(sc.physics_hz);
                // The IMU waits for the host's '!' before streaming (spec 1.1); the pipe buffers it.
                let mut t_us: i64 = 0;
                let mut k: u64 = 0;
                let mut acc = HoverAcc::default();
                let mut airborne_since: Option<i64> = None;
                let mut gps_seq = 0u64;
                while !stop.load(Ordering::SeqCst) {
                    t_us += step_us;
                    let due = start + Duration::from_micros(t_us as u64);
                    if let Some(wait) = due.checked_duration_since(Instant::now()) {
                        std::thread::sleep(wait);
                    }
                    let now_us = start.elapsed().as_micros() as i64;
                    plant.w_cmd_rad_s = model
                        .lock()
                        .map(|mut m| {
                            if esc_nack_at.is_some_and(|a| t_us >= a) {
                                m.failing = true;
                            }
                            m.commands_rad_s(now_us)
                        })
                        .unwrap_or([0.0; 4]);
                    plant.step(step_us);
                    if t_us % 10_000 == 5_000 {
                        imu.first_half(&plant);
                    }
                    if gps_live && t_us % 1_000_000 == 0 {
                        let fix =
                            crate::sim::run::sim_fix(&mut gps_seq, plant.position_m(), now_us);
                        gps_tx.send_replace(Some(fix));
                    }
                    if t_us % 10_000 == 0 && imu_stall_at.is_none_or(|a| t_us < a) {
                        let f = imu.frame(&plant, 10_000);
                        let bytes = f.encode(if k.is_multiple_of(2) { b'C' } else { b'A' });
                        k += 1;
                        if rt.block_on(imu_end.write_all(&bytes)).is_err() {
                            break;
                        }
                        // Hover quality: from settle_s after the vehicle is near its set point.
                        let pos_m = plant.position_m();
                        let z = pos_m[2];
                        if airborne_since.is_none() && z > 0.8 * hover_z {
                            airborne_since = Some(t_us);
                        }
                        if let Some(a) = airborne_since
                            && t_us >= a + (sc.settle_s * 1e6) as i64
                        {
                            let e = plant.euler_rad();
                            acc.add(
                                t_us as f64 / 1e6,
                                [pos_m[0], pos_m[1], z - hover_z],
                                e[0],
                                e[1],
                            );
                        }
                        if progress && t_us % 5_000_000 == 0 {
                            eprintln!(
                                "sim {:5.1} s  z {:6.3} m  roll {:+.3} pitch {:+.3} rad",
                                t_us as f64 / 1e6,
                                z,
                                plant.euler_rad()[0],
                                plant.euler_rad()[1]
                            );
                        }
                    }
                }
                if let Ok(mut h) = hover.lock() {
                    *h = acc.stats();
                }
                t_us
            })?
    };
    let cancel = CancellationToken::new();
    let timer = {
        let cancel = cancel.clone();
        tokio::spawn(async move {
            tokio::select! {
                _ = tokio::time::sleep(duration) => cancel.cancel(),
                _ = cancel.cancelled() => {}
            }
        })
    };
    let mut run_profile = profile.clone();
    run_profile.config.sim.seed = seed;
    let summary = fly::run(
        &run_profile,
        Edges {
            imu: Box::new(host),
            bus: Box::new(SimBus { model, start }),
            gps_fixes: Some(gps_rx),
        },
        FlyOptions {
            log_dir: opts.log_dir.clone(),
            realtime: true,
            handle_signals: true,
            ..Default::default()
        },
        cancel,
    )
    .await;
    timer.abort();
    stop.store(true, Ordering::SeqCst);
    let simulated_us = tokio::task::spawn_blocking(move || sim_thread.join().unwrap_or(0))
        .await
        .unwrap_or(0);
    let hover = hover.lock().map(|h| *h).unwrap_or_default();
    Ok(SimSummary {
        fly: summary?,
        hover,
        simulated_s: simulated_us as f64 / 1e6,
    })
}
