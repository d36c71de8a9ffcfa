//! `uquad sim --mode paced`: the lock-step flight of `sim --fast` (`app::sim_fast`) on its
//! simulated clock, paced to the wall clock (`--speed FACTOR`: simulated seconds per wall
//! second), with the ground-station link and the console served and the logs written by
//! `fly`'s loggers as the run goes. The watchdog judges the simulated clock, so a host that
//! stalls slows the flight instead of halting it: a simulator for practising with a ground
//! station on a busy laptop. `--realtime` stays the test of the real threads.
//!
//! The simulator thread runs the steps; at each frame it takes the links' operator inputs
//! (never waited for), publishes the vehicle's status for the link and the console, and
//! sleeps until the wall clock has caught up with the simulated one. Behind by more than
//! [`STALL`] (the host stalled), it does not race to catch up: the pacing starts again from
//! now, and the flight has simply slowed.
//!
//! A link's timeouts live on the wall clock a ground station lives by: the run's
//! `failsafe.link_timeout_s` is multiplied by `--speed` (at least 1.5 s) by the run's first
//! operator input, recorded in mode.log so that a replay judges the same; the link's own
//! timers are the wall clock's.

use crate::app::fly::gcs_link;
use crate::app::report::SimSummary;
use crate::app::run_dir::{create_run_dir, new_run_id, write_run_config};
use crate::app::sim::SimOptions;
use crate::app::sim_fast::{FastSim, Served};
use crate::config::{GcsEnabled, Profile};
use crate::core::commander::{Mode, OperatorInput};
use crate::core::status::VehicleStatus;
use crate::sim::FRAME_US;
use crate::tasks::notices::Notices;
use crate::tasks::status::StatusReader;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// Behind the wall clock by more than this, the pacing starts again from now (the host
/// stalled: the flight slows instead of racing).
pub const STALL: Duration = Duration::from_millis(100);

/// Operator inputs queued for the flight (taken at each step).
const OPERATOR_QUEUE: usize = 64;

/// The pre-arm verdict is asked this often while disarmed, simulated µs.
const PREARM_EVERY_US: i64 = 1_000_000;

/// Wall-clock pacing of the simulated clock at `speed` simulated seconds per second.
struct Pacer {
    speed: f64,
    /// The wall instant and the simulated time the pacing counts from.
    anchor: (Instant, i64),
    /// Host stalls the pacing restarted after.
    stalls: u64,
}

impl Pacer {
    fn new(speed: f64, t_us: i64) -> Self {
        Pacer {
            speed,
            anchor: (Instant::now(), t_us),
            stalls: 0,
        }
    }

    /// Sleeps until the wall clock reaches simulated `t_us`; far behind, starts again.
    fn wait(&mut self, t_us: i64) {
        let (wall0, sim0) = self.anchor;
        let due = wall0 + Duration::from_secs_f64((t_us - sim0) as f64 / 1e6 / self.speed);
        let now = Instant::now();
        if now > due + STALL {
            self.stalls += 1;
            self.anchor = (now, t_us);
        } else if due > now {
            std::thread::sleep(due - now);
        }
    }
}

/// Runs a paced simulation to its end (`--duration`, a landing after the script, a signal)
/// and returns its summary.
pub async fn run(profile: &Profile, opts: &SimOptions, speed: f64) -> anyhow::Result<SimSummary> {
    let mut profile = profile.clone();
    profile.config.sim.seed = opts.seed.unwrap_or(profile.config.sim.seed);
    let cfg = &profile.config;
    let run_dir = create_run_dir(&opts.log_dir.clone().unwrap_or_else(|| cfg.log.dir.clone()))?;
    let run_id = new_run_id(&run_dir);
    write_run_config(&profile, &run_dir, &run_id)?;
    let (logs, loggers) =
        crate::tasks::logger::spawn_all(&run_dir, cfg.log.queue_records as usize, None).await?;
    let cancel = CancellationToken::new();
    let (operator_tx, operator_rx) = mpsc::channel(OPERATOR_QUEUE);
    // The link's silence is judged on the wall clock: the run's first input scales its
    // timeout (recorded in mode.log, so a replay judges the same; the parameter a ground
    // station reads stays the profile's).
    if speed != 1.0 {
        let _ = operator_tx.try_send(OperatorInput::Param {
            key: "failsafe.link_timeout_s",
            value: cfg.failsafe.link_timeout_s,
        });
    }
    let (status_tx, status_rx) = watch::channel(VehicleStatus::default());
    let links = Links::start(
        &profile,
        opts,
        &run_dir,
        &logs,
        &operator_tx,
        &status_rx,
        &cancel,
    );
    let stop = Arc::new(AtomicBool::new(false));
    tokio::spawn(stop_on_signals(stop.clone(), cancel.clone()));
    let served = Served {
        operator: operator_rx,
        status: status_tx,
        mode: links.notices.mode(),
        next_prearm_us: 0,
        prearm_ok: None,
        speed,
    };
    let thread = {
        let (profile, opts, stop) = (profile.clone(), opts.clone(), stop.clone());
        let out = (logs.clone(), links.notices.clone());
        std::thread::Builder::new()
            .name("sim-paced".into())
            .spawn(move || {
                let run = (run_dir, run_id);
                fly_paced(&profile, &opts, speed, run, out, served, &stop)
            })
    };
    drop(operator_tx);
    let summary = match thread {
        Ok(t) => joined(t).await,
        Err(e) => Err(anyhow::anyhow!("cannot start the simulator thread: {e}")),
    };
    // The links end first (they hold the loggers' senders), then the loggers drain: on
    // every path, an error too.
    cancel.cancel();
    let gcs = links.end().await;
    drop(logs);
    let mut records = crate::logs::PerStream::<u64>::default();
    for l in loggers {
        match l.await {
            Ok(Ok(rep)) => records[rep.stream] = rep.records,
            Ok(Err(e)) => tracing::error!("a logger failed: {e}"),
            Err(e) => tracing::error!("a logger task failed: {e}"),
        }
    }
    let mut summary = summary?;
    summary.fly.gcs = gcs;
    summary.fly.log_records = records;
    Ok(summary)
}

/// The simulator thread's summary once it has ended; a panic is an error with its message.
async fn joined(
    thread: std::thread::JoinHandle<anyhow::Result<SimSummary>>,
) -> anyhow::Result<SimSummary> {
    tokio::task::spawn_blocking(move || thread.join())
        .await
        .map_err(|e| anyhow::anyhow!("the simulator thread could not be joined: {e}"))?
        .map_err(|p| {
            anyhow::anyhow!(
                "the simulator thread panicked: {}",
                crate::tasks::panic_message(p.as_ref())
            )
        })?
}

/// The ground-station link (unless `gcs.enabled = "never"`) and the console, served from the
/// published status; the notices the flight tells them.
struct Links {
    notices: Notices,
    gcs: Option<(tokio::task::JoinHandle<()>, crate::tasks::gcs::GcsStats)>,
}

impl Links {
    fn start(
        profile: &Profile,
        opts: &SimOptions,
        run_dir: &std::path::Path,
        logs: &crate::tasks::logger::LogHub,
        operator: &mpsc::Sender<OperatorInput>,
        status: &watch::Receiver<VehicleStatus>,
        cancel: &CancellationToken,
    ) -> Links {
        let cfg = &profile.config;
        let (notices, notices_rx) = gcs_link::notices(cfg.gcs.enabled != GcsEnabled::Never);
        let gcs = notices_rx.map(|rx| {
            let stats = crate::tasks::gcs::GcsStats::default();
            let run = gcs_link::LinkRun {
                run_dir: run_dir.to_path_buf(),
                logs: logs.clone(),
                notices: notices.clone(),
                boot: Instant::now(),
                stats: stats.clone(),
                cancel: cancel.clone(),
            };
            let inputs = gcs_link::Inputs {
                operator: operator.clone(),
                notices: rx,
                status: StatusReader::Published(status.clone()),
            };
            (
                gcs_link::start(profile, opts.log_dir.as_deref(), run, inputs),
                stats,
            )
        });
        serve_console(profile, operator, status, logs, cancel);
        Links { notices, gcs }
    }

    /// Waits (at most 1 s) for the link to end after the cancel, else stops it; its report.
    async fn end(self) -> Option<crate::tasks::gcs::GcsReport> {
        let (task, stats) = self.gcs?;
        let abort = task.abort_handle();
        if tokio::time::timeout(Duration::from_secs(1), task)
            .await
            .is_err()
        {
            tracing::warn!("the ground-station link did not end within 1 s; stopped");
            abort.abort();
        }
        Some(stats.lock().map(|r| *r).unwrap_or_default())
    }
}

/// The simulator thread: the lock-step flight, paced, until its end or `stop`.
fn fly_paced(
    profile: &Profile,
    opts: &SimOptions,
    speed: f64,
    (run_dir, run_id): (std::path::PathBuf, String),
    links: (crate::tasks::logger::LogHub, Notices),
    served: Served,
    stop: &AtomicBool,
) -> anyhow::Result<SimSummary> {
    let seed = profile.config.sim.seed;
    let duration_us = (crate::app::sim::duration_s(opts, profile) * 1e6).round() as i64;
    let mut sim = FastSim::new(profile, opts, seed, run_dir, run_id, Some(links));
    sim.served = Some(served);
    let mut pacer = Pacer::new(speed, 0);
    let mut stopping = false;
    loop {
        let (t_us, _) = sim.clock_us();
        if t_us >= duration_us || !sim.advance() {
            break;
        }
        let (t_us, _) = sim.clock_us();
        if t_us % FRAME_US != 0 {
            continue;
        }
        if stop.load(Ordering::SeqCst) && !stopping {
            stopping = true;
            sim.shut_down();
        }
        publish(&mut sim, t_us);
        pacer.wait(t_us);
    }
    if pacer.stalls > 0 {
        tracing::warn!(
            stalls = pacer.stalls,
            "the host fell behind the pacing; the flight slowed instead"
        );
    }
    sim.finish()
}

/// The vehicle's status for the link and the console, at a frame; the pre-arm verdict once
/// a simulated second while disarmed.
fn publish(sim: &mut FastSim<'_>, t_us: i64) {
    let Some(served) = sim.served.as_ref() else {
        return;
    };
    let mode = served.mode.get();
    let mut prearm = served.prearm_ok;
    let due = t_us >= served.next_prearm_us;
    if mode == Mode::Disarmed && due {
        prearm = Some(sim.prearm_passes());
    }
    let status = sim.status(mode, prearm);
    if let Some(served) = sim.served.as_mut() {
        if mode == Mode::Disarmed && due {
            served.next_prearm_us = t_us + PREARM_EVERY_US;
        }
        served.prearm_ok = prearm;
        served.status.send_replace(status);
    }
}

/// The console socket (`console.socket`), as `fly` serves it: typed commands into the
/// flight, a statistics line from the published status.
fn serve_console(
    profile: &Profile,
    operator: &mpsc::Sender<OperatorInput>,
    status: &watch::Receiver<VehicleStatus>,
    logs: &crate::tasks::logger::LogHub,
    cancel: &CancellationToken,
) {
    let path = profile.config.console.socket.clone();
    if path.as_os_str().is_empty() {
        return;
    }
    let stats: crate::console::StatsFn = {
        let status = status.clone();
        Arc::new(move || stats_line(&status.borrow()))
    };
    let drops = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let (tx, cancel, logs) = (operator.clone(), cancel.clone(), logs.clone());
    tokio::spawn(async move {
        if let Err(e) = crate::console::serve(path.clone(), stats, tx, drops, cancel).await {
            tracing::error!("console socket {}: {e}", path.display());
            logs.err(format!("console socket {}: {e}", path.display()));
        }
    });
}

/// The console's statistics line of a paced run.
fn stats_line(s: &VehicleStatus) -> String {
    let mut line = format!("stats frames={} mode={}", s.imu_frames, s.mode.name());
    if let Some(l) = s.live {
        line += &format!(
            " step={} z={:.3} setpoint_z={:.2} roll={:+.3} pitch={:+.3} yaw={:+.3}",
            l.step, l.x[2], l.setpoint_m[2], l.x[3], l.x[4], l.x[5]
        );
    }
    if let Some(rc) = s.rc {
        line += &rc.words();
    }
    line
}

/// SIGINT, SIGTERM or SIGHUP: the motors stopped at once, in the air too, and the run ends (the
/// logs and the report written).
async fn stop_on_signals(stop: Arc<AtomicBool>, cancel: CancellationToken) {
    use tokio::signal::unix::{SignalKind, signal};
    let kinds = [
        SignalKind::interrupt(),
        SignalKind::terminate(),
        SignalKind::hangup(),
    ];
    let Ok(mut signals) = kinds.into_iter().map(signal).collect::<Result<Vec<_>, _>>() else {
        tracing::error!("cannot install signal handlers");
        return;
    };
    let [a, b, c] = &mut signals[..] else {
        return;
    };
    tokio::select! {
        _ = a.recv() => {}
        _ = b.recv() => {}
        _ = c.recv() => {}
        _ = cancel.cancelled() => return,
    }
    tracing::warn!("signal: stopping the motors and ending the run");
    stop.store(true, Ordering::SeqCst);
}
