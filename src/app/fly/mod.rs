//! `uquad fly`: the flight program as Tokio tasks over bounded channels, in named phases.
//!
//! ```text
//! imu_reader --frames (mpsc)--> estimator --estimates (mpsc 1)--> controller --command--> esc_writer
//!                                  ^                                  |        (mailbox)   (own thread)
//!                                  +------ feedback: next u (watch) --+
//! stdin lines, consoles, sim operator --operator inputs (mpsc)--^ (to the estimator)
//! every stream --records (try_send, drops counted)--> logger[stream] --> <run>/<stream>.log
//! ```
//!
//! Phases: open the run folder → start the actuator (the ESC writer boots disabled) → start
//! the watchdog → spawn the control thread (IMU reader, estimator, controller on a
//! current-thread runtime, SCHED_FIFO when permitted) → serve the operator (signals, stdin
//! keys, console, systemd) → shut down. Shutdown flows from the motors: zero and disable
//! first, then the control path stops, then the loggers drain and flush.

mod control;
pub(crate) mod gcs_link;
mod operators;

use crate::app::report::FlySummary;
use crate::app::run_dir::{create_run_dir, new_run_id, write_run_config};
use crate::config::Profile;
use crate::core::commander::OperatorInput;
use crate::core::flight::FlightRecord;
use crate::core::gps::LiveFix;
use crate::hw::esc_bus::EscBus;
use crate::logs::{Record, halt_line};
use crate::tasks::controller::Live;
use crate::tasks::esc_writer::{self, EscMailbox, EscParams, EscStatus};
use crate::tasks::gcs::GcsStats;
use crate::tasks::gps_client::GpsStats;
use crate::tasks::heartbeats::Heartbeats;
use crate::tasks::imu_reader::ImuStats;
use crate::tasks::logger::{self, LogHub, LogStall, LoggerReport};
use crate::tasks::notices::Notices;
use crate::tasks::watchdog::{self, WatchdogStatus};
use anyhow::Context;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// The IMU byte stream: a serial port, a pty or an in-memory pipe.
pub trait ImuIo: AsyncRead + AsyncWrite + Unpin + Send + 'static {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send + 'static> ImuIo for T {}

/// The edges a run is wired to.
pub struct Edges {
    pub imu: Box<dyn ImuIo>,
    pub bus: Box<dyn EscBus>,
    /// Where gps.mode = "gpsd" takes its fixes from: None = a gpsd client on gps.server; Some
    /// = fixes published by the caller (the simulator's true position).
    pub gps_fixes: Option<watch::Receiver<Option<LiveFix>>>,
    /// Where the controller publishes its newest step (the console reads it); a caller that
    /// passes its own sender watches the flight too (the simulator's hover window).
    pub live: Option<watch::Sender<Option<Live>>>,
    /// More operator inputs beside stdin and the consoles (the simulator's scripted operator).
    pub operator: Option<mpsc::Receiver<OperatorInput>>,
    /// The RC receiver's UART (`rc.protocol`), opened: its reader runs beside the flight.
    pub rc: Option<Box<dyn tokio::io::AsyncRead + Send + Unpin>>,
}

/// How a run behaves beyond its configuration.
#[derive(Debug, Clone, Default)]
pub struct FlyOptions {
    /// Folder under which the run folder is created (default: the profile's `log.dir`).
    pub log_dir: Option<PathBuf>,
    /// Ask for SCHED_FIFO on the control thread and lock memory (warns when not permitted).
    pub realtime: bool,
    /// Read the original's manual-mode keys from stdin.
    pub stdin_keys: bool,
    /// Fault injection: a logger stalls.
    pub log_stall: Option<LogStall>,
    /// Handle SIGINT/SIGTERM (the command does; tests cancel instead).
    pub handle_signals: bool,
    /// Fault injection: from this control step on, each control step takes this long.
    pub control_delay: Option<(u32, Duration)>,
    /// Fault injection (tests): the control step of this number panics.
    pub control_panic_at: Option<u32>,
    /// `fly --arm`: arm once the flight side is ready (settled; calibrated at rest with its
    /// estimate converged).
    pub arm_at_start: bool,
    /// Arming does not require SCHED_FIFO (`--allow-no-rt`, the simulator).
    pub realtime_waived: bool,
    /// Serve the ground-station link (`gcs.enabled` decides, per command).
    pub gcs: bool,
}

/// The handles every phase of a run shares; cheap to clone.
#[derive(Clone)]
struct RunHandles {
    run_dir: PathBuf,
    logs: LogHub,
    /// The run's clock and the watchdog's inbox.
    beats: Arc<Heartbeats>,
    mailbox: Arc<EscMailbox>,
    esc_status: Arc<EscStatus>,
    wd_status: Arc<WatchdogStatus>,
    imu_stats: Arc<ImuStats>,
    gps_stats: Arc<GpsStats>,
    live: watch::Receiver<Option<Live>>,
    /// Console events missed by slow consoles.
    console_drops: Arc<std::sync::atomic::AtomicU64>,
    /// The commander's events and commands' outcomes, for the ground-station link.
    notices: Notices,
    gcs_stats: Option<GcsStats>,
    /// The pre-arm checks' verdict as the estimator task last checked it.
    prearm_verdict: Arc<crate::tasks::prearm::PrearmVerdict>,
    /// systemd's notification socket, when run as a `Type=notify` service.
    notifier: Option<Arc<crate::hw::notify::Notifier>>,
    cancel: CancellationToken,
}

impl RunHandles {
    fn new(
        run_dir: PathBuf,
        logs: LogHub,
        live_tx: &watch::Sender<Option<Live>>,
        notices: Notices,
        gcs: bool,
        cancel: CancellationToken,
    ) -> Self {
        RunHandles {
            run_dir,
            logs,
            beats: Arc::new(Heartbeats::new(Instant::now())),
            mailbox: Arc::new(EscMailbox::default()),
            esc_status: Arc::new(EscStatus::default()),
            wd_status: Arc::new(WatchdogStatus::default()),
            imu_stats: Arc::new(ImuStats::default()),
            gps_stats: Arc::new(GpsStats::default()),
            live: live_tx.subscribe(),
            console_drops: Arc::default(),
            notices,
            gcs_stats: gcs.then(GcsStats::default),
            prearm_verdict: Arc::default(),
            notifier: crate::hw::notify::Notifier::from_env().map(Arc::new),
            cancel,
        }
    }
}

/// The threads to join at shutdown, motors first, and the ground-station link's task.
struct Threads {
    esc: JoinHandle<()>,
    watchdog: JoinHandle<()>,
    control: JoinHandle<anyhow::Result<control::Reports>>,
    gcs: Option<tokio::task::JoinHandle<()>>,
    /// The RC receiver reader's counters (it ends at cancel).
    rc: Option<Arc<crate::tasks::rc_reader::RcStats>>,
}

/// Runs a flight until `cancel` fires (a signal, a quit key, the IMU stream ending, a start-up
/// failure, a halt) and returns its summary. The motors are stopped on every path out.
pub async fn run(
    profile: &Profile,
    mut edges: Edges,
    opts: FlyOptions,
    cancel: CancellationToken,
) -> anyhow::Result<FlySummary> {
    let (run_dir, logs, loggers) = open_run_folder(profile, &opts).await?;
    let live_tx = edges.live.take().unwrap_or_else(|| watch::channel(None).0);
    // The link's queue exists before the flight starts: it hears the commander's first
    // events.
    let (notices, notices_rx) = gcs_link::notices(opts.gcs);
    let h = RunHandles::new(run_dir, logs, &live_tx, notices, opts.gcs, cancel);
    crate::tasks::esc_writer::halt_on_any_panic(&h.mailbox);
    let esc = start_actuator(profile, edges.bus, &h, opts.realtime)?;
    // Any early return from here on (a thread that cannot start) still stops the ESCs.
    let _esc_guard = operators::StopEscOnDrop(h.mailbox.clone());
    let watchdog = start_watchdog(profile, &h, opts.realtime)?;
    let (operator_tx, operator_rx) = mpsc::channel::<OperatorInput>(OPERATOR_QUEUE);
    let gps_live = control::live_fixes(profile, edges.gps_fixes, &h);
    let log_problem = watch_log_folder(&h);
    let control = control::spawn(
        profile,
        control::Inputs {
            imu: edges.imu,
            gps_live: gps_live.clone(),
            operator: operator_rx,
            live: live_tx,
            log_problem: log_problem.clone(),
        },
        &opts,
        &h,
    )?;
    let rc = edges
        .rc
        .take()
        .map(|port| (rc_reader(profile, &h, &operator_tx), port));
    // The vehicle's status as every watcher reads it: the console and the link alike.
    let status = crate::tasks::status::StatusSources {
        mode: h.notices.mode(),
        live: h.live.clone(),
        gps: gps_live,
        log_problem,
        watchdog: h.wd_status.clone(),
        imu: h.imu_stats.clone(),
        esc: h.esc_status.clone(),
        esc_addresses: profile.motor_map().addresses,
        control_cpu: crate::hw::cpu_clock::thread_clock(&control),
        prearm: h.prearm_verdict.clone(),
        rc: rc.as_ref().map(|(reader, _)| reader.stats.clone()),
    };
    serve_operator(profile, &opts, &h, &operator_tx, &status);
    let gcs = notices_rx.map(|notices| {
        let link = gcs_link::Inputs {
            operator: operator_tx.clone(),
            notices,
            status: crate::tasks::status::StatusReader::Tasks(Box::new(status)),
        };
        gcs_link::spawn(profile, &opts, &h, link)
    });
    if let Some(extra) = edges.operator {
        tokio::spawn(operators::forward(
            extra,
            operator_tx.clone(),
            h.cancel.clone(),
        ));
    }
    let rc_stats = rc.map(|(reader, port)| {
        let stats = reader.stats.clone();
        tokio::spawn(reader.run(port, h.cancel.clone()));
        stats
    });
    h.cancel.cancelled().await;
    drop(operator_tx);
    let threads = Threads {
        esc,
        watchdog,
        control,
        gcs,
        rc: rc_stats,
    };
    Ok(shut_down(h, threads, loggers).await)
}

/// The RC receiver's reader: frames to operator inputs, the kill switch to the ESC writer.
fn rc_reader(
    profile: &Profile,
    h: &RunHandles,
    operator: &mpsc::Sender<OperatorInput>,
) -> crate::tasks::rc_reader::RcReader {
    let cfg = &profile.config;
    let decoder = crate::core::rc::Decoder::new(cfg.rc.protocol);
    let link = crate::core::rc::link::RcLink::new(
        cfg.rc.map(),
        cfg.rc.modes.clone(),
        cfg.failsafe.rc_timeout_s,
    );
    crate::tasks::rc_reader::RcReader {
        decoder,
        link,
        mailbox: h.mailbox.clone(),
        operator: operator.clone(),
        beats: h.beats.clone(),
        stats: Arc::new(crate::tasks::rc_reader::RcStats::stale_after(
            std::time::Duration::from_secs_f64(cfg.failsafe.rc_timeout_s),
        )),
        esc: h.esc_status.clone(),
        kill: crate::tasks::rc_reader::KillWatch::Off,
        frame_at: None,
    }
}

/// Operator inputs queued for the control path (it takes them at each frame; beyond this,
/// the senders are told the control path is not taking commands).
const OPERATOR_QUEUE: usize = 64;

/// The run folder's pre-arm probe, once a second on the main runtime.
fn watch_log_folder(h: &RunHandles) -> watch::Receiver<Option<String>> {
    let (tx, rx) = watch::channel(None);
    tokio::spawn(crate::tasks::prearm::watch_log_dir(
        h.run_dir.clone(),
        tx,
        h.cancel.clone(),
    ));
    rx
}

type Loggers = Vec<tokio::task::JoinHandle<std::io::Result<LoggerReport>>>;

/// Phase 1: the run folder, its self-contained configuration and one logger per stream.
async fn open_run_folder(
    profile: &Profile,
    opts: &FlyOptions,
) -> anyhow::Result<(PathBuf, LogHub, Loggers)> {
    let cfg = &profile.config;
    let parent = opts.log_dir.clone().unwrap_or_else(|| cfg.log.dir.clone());
    let run_dir = create_run_dir(&parent)?;
    let run_id = new_run_id(&run_dir);
    write_run_config(profile, &run_dir, &run_id)?;
    let (logs, loggers) =
        logger::spawn_all(&run_dir, cfg.log.queue_records as usize, opts.log_stall)
            .await
            .with_context(|| format!("cannot create the logs in {}", run_dir.display()))?;
    // The run's name first in the streams that have a header, before any other record.
    logs.log(Record::RunId(run_id.clone()));
    if cfg.gps.mode == crate::config::GpsMode::Gpsd {
        logs.log(Record::GpsHeader(run_id));
    }
    logs.err(format!(
        "uquad {} run {}",
        env!("CARGO_PKG_VERSION"),
        run_dir.display()
    ));
    tracing::info!(run_dir = %run_dir.display(), "run started");
    if opts.realtime
        && let Err(e) = crate::tasks::lock_memory()
    {
        tracing::warn!("{e}; memory may be paged");
    }
    Ok((run_dir, logs, loggers))
}

/// Phase 2: the ESC writer's thread; it boots disabled and owns the bus.
fn start_actuator(
    profile: &Profile,
    bus: Box<dyn EscBus>,
    h: &RunHandles,
    realtime: bool,
) -> anyhow::Result<JoinHandle<()>> {
    let cfg = &profile.config;
    esc_writer::spawn(
        bus,
        EscParams {
            map: profile.motor_map(),
            timing: cfg.esc_timing(),
        },
        h.mailbox.clone(),
        h.esc_status.clone(),
        h.beats.clone(),
        realtime,
    )
    .context("cannot start the ESC writer thread")
}

/// Phase 3: the watchdog's thread; it halts through the ESC writer and ends the run.
fn start_watchdog(
    profile: &Profile,
    h: &RunHandles,
    realtime: bool,
) -> anyhow::Result<JoinHandle<()>> {
    let logs = h.logs.clone();
    let on_halt = move |halt| {
        tracing::error!("{}", halt_line(&halt));
        logs.log(Record::Flight(FlightRecord::Halt(halt)));
    };
    watchdog::spawn(
        profile.config.watchdog.params(),
        h.beats.clone(),
        h.wd_status.clone(),
        watchdog::HaltPath {
            mailbox: h.mailbox.clone(),
            esc: h.esc_status.clone(),
            addresses: profile.motor_map().addresses,
            retry: Duration::from_millis(u64::from(profile.config.watchdog.halt_retry_ms)),
        },
        on_halt,
        h.cancel.clone(),
        realtime,
    )
    .context("cannot start the watchdog thread")
}

/// Phase 5: signals, stdin's lines, the console socket and systemd, on the main runtime.
fn serve_operator(
    profile: &Profile,
    opts: &FlyOptions,
    h: &RunHandles,
    operator_tx: &mpsc::Sender<OperatorInput>,
    status: &crate::tasks::status::StatusSources,
) {
    let cfg = &profile.config;
    if opts.stdin_keys {
        tokio::spawn(operators::read_terminal(
            operator_tx.clone(),
            h.cancel.clone(),
        ));
    }
    // The first signal stops the motors and ends the run in order; a third exits once the
    // motors' stop has settled.
    if opts.handle_signals {
        let settle = Duration::from_millis(u64::from(cfg.watchdog.halt_retry_ms) + 500);
        tokio::spawn(operators::handle_signals(
            h.mailbox.clone(),
            h.esc_status.clone(),
            Some(h.logs.clone()),
            h.cancel.clone(),
            settle,
        ));
    }
    if !cfg.console.socket.as_os_str().is_empty() {
        let stats: crate::console::StatsFn = {
            let (h, status) = (h.clone(), status.clone());
            Arc::new(move || operators::console_stats(&h, &status.read()))
        };
        let path = cfg.console.socket.clone();
        let drops = h.console_drops.clone();
        let (tx, cancel, logs) = (operator_tx.clone(), h.cancel.clone(), h.logs.clone());
        tokio::spawn(async move {
            if let Err(e) = crate::console::serve(path.clone(), stats, tx, drops, cancel).await {
                tracing::error!("console socket {}: {e}", path.display());
                logs.err(format!("console socket {}: {e}", path.display()));
            }
        });
    }
    // systemd: ready once the IMU delivers frames (the devices are open and talking), then
    // watchdog pings only while the internal watchdog is healthy.
    if let Some(n) = h.notifier.clone() {
        tokio::spawn(operators::notify_systemd(n, h.clone()));
    }
}

/// Phase 6: motors first (zero and disable, then wait for the writer), then the watchdog and
/// the control path; the closing lines into err.log; then the loggers drain and flush.
async fn shut_down(h: RunHandles, threads: Threads, loggers: Loggers) -> FlySummary {
    if let Some(n) = &h.notifier {
        n.send("STOPPING=1");
    }
    h.mailbox.shutdown();
    h.wd_status.stop();
    let watchdog = joined("watchdog", threads.watchdog).await.err();
    let esc = joined("ESC writer", threads.esc)
        .await
        .err()
        .map(|e| format!("{e}; the ESCs stop by themselves once their writes stop"));
    let (reports, control) = match joined("control", threads.control).await {
        Ok(Ok(r)) => (r, None),
        Ok(Err(e)) => (control::Reports::default(), Some(format!("{e:#}"))),
        Err(e) => (control::Reports::default(), Some(e)),
    };
    // The link ends at cancel; joined so that its report is final (and no parameter is
    // written) before the summary.
    if let Some(gcs) = threads.gcs
        && tokio::time::timeout(Duration::from_secs(1), gcs)
            .await
            .is_err()
    {
        tracing::warn!("the ground-station link did not end within 1 s");
    }
    let not_started = reports.estimator.start_failure.clone();
    let errors: Vec<String> = [control, esc, watchdog, not_started]
        .into_iter()
        .flatten()
        .collect();
    let error = (!errors.is_empty()).then(|| errors.join("; "));
    if let Some(e) = &error {
        tracing::error!("{e}");
    }
    let mut summary = summarise(&h, reports, error);
    summary.rc_kills = threads.rc.as_ref().map(|s| s.kills()).unwrap_or_default();
    summary.rc = threads.rc.map(|s| s.counts());
    for r in summary.closing_records() {
        h.logs.log(r);
    }
    drop(h);
    for l in loggers {
        match l.await {
            Ok(Ok(rep)) => summary.log_records[rep.stream] = rep.records,
            Ok(Err(e)) => tracing::error!("a logger failed: {e}"),
            Err(e) => tracing::error!("a logger task failed: {e}"),
        }
    }
    summary
}

/// Joins a flight thread off the runtime; a panic becomes an error with its message.
async fn joined<T: Send + 'static>(name: &str, t: JoinHandle<T>) -> Result<T, String> {
    match tokio::task::spawn_blocking(move || t.join()).await {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(p)) => Err(format!(
            "the {name} thread panicked: {}",
            crate::tasks::panic_message(p.as_ref())
        )),
        Err(e) => Err(format!("the {name} thread could not be joined: {e}")),
    }
}

/// The run's counters, gathered from every part.
fn summarise(h: &RunHandles, r: control::Reports, error: Option<String>) -> FlySummary {
    let load = |a: &std::sync::atomic::AtomicU64| a.load(Ordering::Relaxed);
    FlySummary {
        run_dir: h.run_dir.clone(),
        frames: load(&h.imu_stats.frames),
        steps: r.estimator.steps,
        discarded_bytes: load(&h.imu_stats.discarded_bytes),
        rejected_frames: load(&h.imu_stats.rejected_frames),
        dropped_frames: load(&h.imu_stats.dropped_frames),
        late_feedback: r.estimator.late_feedback,
        ekf_errors: r.estimator.ekf_errors,
        gps_updates: r.estimator.gps_updates,
        ekf_gated: r.estimator.ekf_gated,
        gpsd_connects: load(&h.gps_stats.connects),
        gpsd_disconnects: load(&h.gps_stats.disconnects),
        gpsd_fixes: load(&h.gps_stats.fixes),
        saturated_commands: r.controller.saturated,
        esc_writes: load(&h.esc_status.writes),
        esc_failed_writes: load(&h.esc_status.failed_writes),
        esc_commands: load(&h.esc_status.commands),
        esc_stop_reason: h.esc_status.stop_reason().map(|r| r.name().to_string()),
        log_drops: h.logs.dropped(),
        log_io_errors: h.logs.io_errors(),
        console_drops: load(&h.console_drops),
        rc: None,
        rc_kills: Vec::new(),
        gcs: h
            .gcs_stats
            .as_ref()
            .map(|s| s.lock().map(|r| *r).unwrap_or_default()),
        stderr_drops: crate::console::stderr_drops(),
        log_records: Default::default(),
        latency: h.esc_status.latency.figures(),
        deadline_misses: load(&h.wd_status.deadline_misses),
        host_stalls: load(&h.wd_status.host_stalls),
        watchdog_gap_max_us: load(&h.wd_status.longest_gap_us),
        halt: h.wd_status.halt(),
        error,
        commander: r.estimator.commander,
    }
}
