//! `uquad fly`: the flight program as Tokio tasks over bounded channels.
//!
//! ```text
//! imu_reader --frames (mpsc)--> estimator --estimates (mpsc 1)--> controller --command--> esc_writer
//!                                  ^                                  |        (mailbox)   (own thread)
//!                                  +------ feedback: next u (watch) --+
//! stdin keys --manual (mpsc)------------------------------------------^
//! every stream --records (try_send, drops counted)--> logger[stream] --> <run>/<stream>.log
//! ```
//!
//! The control path (IMU reader, estimator, controller) runs on its own thread with a
//! current-thread runtime, at SCHED_FIFO when permitted; the ESC writer has its own thread
//! (blocking I2C); loggers run on the caller's runtime. Shutdown flows from the motors: zero and
//! disable first, then the control path stops, then the loggers drain and flush.

use crate::config::{Config, Profile};
use crate::core::control::ManualCommand;
use crate::core::flight::GpsFeed;
use crate::hw::esc_bus::EscBus;
use crate::tasks::controller::{ControllerReport, ControllerTask};
use crate::tasks::esc_writer::{self, EscMailbox, EscParams, EscStatus};
use crate::tasks::estimator::{EstimatorReport, EstimatorTask, Feedback};
use crate::tasks::gps_client::{self, GpsStats};
use crate::tasks::imu_reader::{self, ImuStats};
use crate::tasks::logger::{self, LogStall, STREAMS};
use crate::tasks::watchdog::{self, Halt, Heartbeats, WatchdogStatus};
use anyhow::Context;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;
use tracing::Instrument;

/// The IMU byte stream: a serial port, a pty or an in-memory pipe.
pub trait ImuIo: AsyncRead + AsyncWrite + Unpin + Send + 'static {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send + 'static> ImuIo for T {}

/// The edges a run is wired to.
pub struct Edges {
    pub imu: Box<dyn ImuIo>,
    pub bus: Box<dyn EscBus>,
    /// Where gps.mode = "gpsd" takes its fixes from: None = a gpsd client on gps.server; Some
    /// = fixes published by the caller (the simulator's true position).
    pub gps_fixes: Option<watch::Receiver<Option<gps_client::LiveFix>>>,
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
}

/// What a run did.
#[derive(Debug, Clone)]
pub struct FlySummary {
    pub run_dir: PathBuf,
    pub frames: u64,
    pub steps: u64,
    pub discarded_bytes: u64,
    pub rejected_frames: u64,
    pub dropped_frames: u64,
    pub late_feedback: u64,
    pub ekf_errors: u64,
    pub gps_updates: u64,
    /// gpsd sessions opened and lost, and fixes received.
    pub gpsd_connects: u64,
    pub gpsd_disconnects: u64,
    pub gpsd_fixes: u64,
    pub saturated_commands: u64,
    pub esc_writes: u64,
    pub esc_failed_writes: u64,
    pub esc_commands: u64,
    pub esc_stop_reason: Option<String>,
    /// Dropped records per stream, in [`STREAMS`] order.
    pub log_drops: [u64; 7],
    /// Records written per stream.
    pub log_records: [u64; 7],
    /// Frame arrival → ESC write, µs.
    pub latencies_us: Vec<u32>,
    pub deadline_misses: u64,
    /// The watchdog's halt, if it tripped.
    pub halt: Option<Halt>,
    /// Why the run ended with an error, if it did (motors were stopped first).
    pub error: Option<String>,
}

impl FlySummary {
    /// A summary with nothing counted yet.
    pub fn empty(run_dir: PathBuf) -> Self {
        FlySummary {
            run_dir,
            frames: 0,
            steps: 0,
            discarded_bytes: 0,
            rejected_frames: 0,
            dropped_frames: 0,
            late_feedback: 0,
            ekf_errors: 0,
            gps_updates: 0,
            gpsd_connects: 0,
            gpsd_disconnects: 0,
            gpsd_fixes: 0,
            saturated_commands: 0,
            esc_writes: 0,
            esc_failed_writes: 0,
            esc_commands: 0,
            esc_stop_reason: None,
            log_drops: [0; 7],
            log_records: [0; 7],
            latencies_us: Vec::new(),
            deadline_misses: 0,
            halt: None,
            error: None,
        }
    }

    pub fn log_drops_total(&self) -> u64 {
        self.log_drops.iter().sum()
    }

    /// Latency percentiles (p50, p99, max), µs.
    pub fn latency_percentiles(&self) -> (u32, u32, u32) {
        let mut lat = self.latencies_us.clone();
        lat.sort_unstable();
        let pct = |q: f64| {
            lat.get(((lat.len() as f64 - 1.0) * q).round() as usize)
                .copied()
                .unwrap_or(0)
        };
        (pct(0.5), pct(0.99), lat.last().copied().unwrap_or(0))
    }

    /// The flight report (`--report FILE`).
    pub fn report(&self) -> serde_json::Value {
        let (p50, p99, max) = self.latency_percentiles();
        let run_dir = std::fs::canonicalize(&self.run_dir).unwrap_or_else(|_| self.run_dir.clone());
        serde_json::json!({
            "frames": self.frames,
            "steps": self.steps,
            "latency_us": { "p50": p50, "p99": p99, "max": max },
            "deadline_misses": self.deadline_misses,
            "log_drops": self.log_drops_total(),
            "watchdog_trips": u64::from(self.halt.is_some()),
            "halt": self.halt.map(|h| serde_json::json!({
                "reason": h.trip.reason.name(),
                "latency_ms": h.latency_ms(),
                "event_s": h.trip.event_us as f64 / 1e6,
                "halt_s": h.halt_us as f64 / 1e6,
            })),
            "run_dir": run_dir,
            "log_drops_by_stream": STREAMS.iter().zip(self.log_drops).map(|(s, d)| (s.to_string(), d)).collect::<std::collections::BTreeMap<_, _>>(),
            "esc": {
                "commands": self.esc_commands,
                "writes": self.esc_writes,
                "failed_writes": self.esc_failed_writes,
                "stop_reason": self.esc_stop_reason,
            },
            "imu": {
                "discarded_bytes": self.discarded_bytes,
                "rejected_frames": self.rejected_frames,
                "dropped_frames": self.dropped_frames,
            },
            "gps": {
                "updates": self.gps_updates,
                "gpsd_connects": self.gpsd_connects,
                "gpsd_disconnects": self.gpsd_disconnects,
                "gpsd_fixes": self.gpsd_fixes,
            },
            "error": self.error,
        })
    }

    /// Writes the report as JSON to `path`.
    pub fn write_report(&self, path: &Path) -> anyhow::Result<()> {
        let text = serde_json::to_string_pretty(&self.report())?;
        std::fs::write(path, text + "\n")
            .with_context(|| format!("cannot write the report {}", path.display()))
    }

    /// The exit summary, a few lines for a person.
    pub fn text(&self) -> String {
        let (p50, p99, max) = self.latency_percentiles();
        let drops: Vec<String> = STREAMS
            .iter()
            .zip(self.log_drops)
            .filter(|(_, d)| *d > 0)
            .map(|(s, d)| format!("{s} {d}"))
            .collect();
        format!(
            "run {}\n  frames {} (discarded bytes {}, rejected frames {}, dropped {}), Kalman steps {}, GPS samples fused {}\n  \
             ESC: {} commands, {} writes, {} failed; stopped: {}\n  \
             latency frame -> ESC write: p50 {} us, p99 {} us, max {} us; deadline misses {}\n  \
             watchdog: {}\n  \
             log drops: {}{}",
            self.run_dir.display(),
            self.frames,
            self.discarded_bytes,
            self.rejected_frames,
            self.dropped_frames,
            self.steps,
            self.gps_updates,
            self.esc_commands,
            self.esc_writes,
            self.esc_failed_writes,
            self.esc_stop_reason.as_deref().unwrap_or("never started"),
            p50,
            p99,
            max,
            self.deadline_misses,
            match self.halt {
                Some(h) => format!(
                    "HALT, reason {}, {:.3} ms after the event",
                    h.trip.reason.name(),
                    h.latency_ms()
                ),
                None => "no trip".to_string(),
            },
            if drops.is_empty() {
                "none".to_string()
            } else {
                drops.join(", ")
            },
            self.error
                .as_ref()
                .map(|e| format!("\n  error: {e}"))
                .unwrap_or_default()
        )
    }
}

/// Seconds since the Unix epoch as a UTC `YYYYMMDD-HHMMSS` (no time-zone database needed).
fn utc_stamp(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    // Civil from days (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}{m:02}{d:02}-{:02}{:02}{:02}",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// Creates a new, unique run folder under `parent`: `<UTC time>`, or `<UTC time>-N` when runs
/// start in the same second (creation is atomic, so concurrent runs never share one).
pub fn create_run_dir(parent: &Path) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(parent)
        .with_context(|| format!("cannot create the log folder {}", parent.display()))?;
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let base = utc_stamp(secs);
    for n in 0..10_000u32 {
        let name = if n == 0 {
            base.clone()
        } else {
            format!("{base}-{n}")
        };
        let dir = parent.join(name);
        match std::fs::create_dir(&dir) {
            Ok(()) => return Ok(dir),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => {
                return Err(e).with_context(|| format!("cannot create {}", dir.display()));
            }
        }
    }
    anyhow::bail!("no free run folder name under {}", parent.display())
}

/// Makes the run folder self-contained: copies the data files the profile names and writes
/// the resolved configuration pointing at the copies, so `uquad replay <run>` works anywhere.
pub fn write_run_config(profile: &Profile, run_dir: &Path) -> anyhow::Result<()> {
    let mut c: Config = profile.config.clone();
    let copy = |p: &mut PathBuf| -> anyhow::Result<()> {
        let name = p
            .file_name()
            .map(PathBuf::from)
            .with_context(|| format!("{} has no file name", p.display()))?;
        std::fs::copy(&*p, run_dir.join(&name))
            .with_context(|| format!("cannot copy {} into {}", p.display(), run_dir.display()))?;
        *p = name;
        Ok(())
    };
    copy(&mut c.imu.calib_file)?;
    copy(&mut c.control.k_prop_file)?;
    copy(&mut c.control.k_int_file)?;
    copy(&mut c.control.lqr_q_file)?;
    copy(&mut c.control.lqr_r_file)?;
    c.log.dir = PathBuf::from("..");
    let text = toml::to_string(&c).context("cannot serialise the configuration")?;
    let header = "# The resolved configuration of this run (uquad writes it; paths are relative \
                  to this folder).\n";
    std::fs::write(run_dir.join("config.toml"), format!("{header}{text}"))
        .with_context(|| format!("cannot write {}", run_dir.join("config.toml").display()))
}

fn lock_memory() {
    // SAFETY: mlockall takes flags only.
    let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if rc != 0 {
        tracing::warn!(
            "mlockall not permitted ({}); memory may be paged",
            std::io::Error::last_os_error()
        );
    }
}

/// Runs a flight until `cancel` fires (a signal, a quit key, the IMU stream ending, a start-up
/// failure) and returns its summary. The motors are stopped on every path out.
pub async fn run(
    profile: &Profile,
    edges: Edges,
    opts: FlyOptions,
    cancel: CancellationToken,
) -> anyhow::Result<FlySummary> {
    let cfg = &profile.config;
    let parent = opts.log_dir.clone().unwrap_or_else(|| cfg.log.dir.clone());
    let run_dir = create_run_dir(&parent)?;
    write_run_config(profile, &run_dir)?;
    let (logs, logger_handles) =
        logger::spawn_all(&run_dir, cfg.log.queue_records as usize, opts.log_stall)
            .await
            .with_context(|| format!("cannot create the logs in {}", run_dir.display()))?;
    logs.err(format!(
        "uquad {} run {}",
        env!("CARGO_PKG_VERSION"),
        run_dir.display()
    ));
    tracing::info!(run_dir = %run_dir.display(), "run started");
    if opts.realtime {
        lock_memory();
    }

    // The run's clock: every stamp is µs since this instant.
    let start = Instant::now();
    let beats = Arc::new(Heartbeats::new(start));
    // The actuator edge first: it boots disabled and owns the bus.
    let mailbox = Arc::new(EscMailbox::default());
    let esc_status = Arc::new(EscStatus::default());
    if let Ok(mut l) = esc_status.latencies_us.lock() {
        // An hour of commands: the ESC writer does not allocate while flying.
        l.reserve(360_000);
    }
    let esc_thread = esc_writer::spawn(
        edges.bus,
        EscParams {
            map: profile.motor_map(),
            resend: Duration::from_millis(u64::from(cfg.esc.resend_ms)),
            command_timeout: Duration::from_millis(u64::from(cfg.esc.command_timeout_ms)),
        },
        mailbox.clone(),
        esc_status.clone(),
        beats.clone(),
        opts.realtime,
    )
    .context("cannot start the ESC writer thread")?;
    // Any early return from here on (a thread that cannot start) still stops the ESCs.
    let _esc_guard = StopEscOnDrop(mailbox.clone());

    // The watchdog, on its own thread: it halts through the ESC writer and ends the run.
    let wd_status = Arc::new(WatchdogStatus::default());
    let wd_thread = watchdog::spawn(
        cfg.watchdog.params(),
        beats.clone(),
        wd_status.clone(),
        (mailbox.clone(), esc_status.clone()),
        {
            let logs = logs.clone();
            move |h| {
                let line = format!(
                    "watchdog: halt, reason {}; event at {} s, halt at {} s ({:.3} ms later)",
                    h.trip.reason.name(),
                    crate::logs::fmt_time_us(h.trip.event_us),
                    crate::logs::fmt_time_us(h.halt_us),
                    h.latency_ms()
                );
                tracing::error!("{line}");
                logs.err(line);
            }
        },
        cancel.clone(),
        opts.realtime,
    )
    .context("cannot start the watchdog thread")?;

    // Manual keys from stdin and the console.
    let (manual_tx, manual_rx) = mpsc::channel::<ManualCommand>(16);
    let (live_tx, live_rx) = watch::channel(None);
    if opts.stdin_keys {
        tokio::spawn(read_keys(manual_tx.clone(), cancel.clone()));
    }

    // The control path on its own thread.
    let imu_stats = Arc::new(ImuStats::default());
    let gps_stats = Arc::new(GpsStats::default());
    let (gps, gps_live) = match cfg.gps.mode {
        crate::config::GpsMode::Off => (GpsFeed::Off, None),
        crate::config::GpsMode::Gpsd => {
            logs.log(logger::Record::GpsHeader);
            let rx = match edges.gps_fixes {
                Some(rx) => rx,
                None => {
                    let (tx, rx) = watch::channel(None);
                    // On the main runtime: the control path never waits on gpsd.
                    tokio::spawn(gps_client::run(
                        cfg.gps.server.clone(),
                        start,
                        tx,
                        gps_stats.clone(),
                        cancel.clone(),
                    ));
                    rx
                }
            };
            (GpsFeed::Live(None), Some(rx))
        }
        _ => (GpsFeed::fake(profile.fake_positions()), None),
    };
    let estimator_core = profile.estimator_core(false).hold_after_settle();
    let controller_core = profile.controller_core();
    let control_thread = {
        let cancel = cancel.clone();
        let logs = logs.clone();
        let mailbox = mailbox.clone();
        let esc_status = esc_status.clone();
        let imu_stats = imu_stats.clone();
        let beats = beats.clone();
        let control_delay = opts.control_delay;
        let live_tx = live_tx.clone();
        let realtime = opts.realtime;
        std::thread::Builder::new()
            .name("control".into())
            .spawn(
                move || -> anyhow::Result<(EstimatorReport, ControllerReport)> {
                    // Whatever ends this thread (an error, a panic) ends the run.
                    let _end_run = cancel.clone().drop_guard();
                    if realtime {
                        crate::tasks::raise_priority("control", 50);
                    }
                    let rt = tokio::runtime::Builder::new_current_thread()
                        .enable_all()
                        .build()
                        .context("cannot build the control runtime")?;
                    rt.block_on(async move {
                        let (frame_tx, frame_rx) = mpsc::channel(8);
                        let (est_tx, est_rx) = mpsc::channel(1);
                        let (fb_tx, fb_rx) = watch::channel(Feedback {
                            step: 0,
                            u_next: [0.0; 4],
                            mass_kg: 0.0,
                            t_cmd_us: None,
                        });
                        let reader = tokio::spawn(
                            imu_reader::run(
                                edges.imu,
                                beats.clone(),
                                frame_tx,
                                imu_stats,
                                cancel.clone(),
                            )
                            .instrument(tracing::info_span!("imu_reader")),
                        );
                        let controller = tokio::spawn(
                            ControllerTask {
                                core: controller_core,
                                estimates: est_rx,
                                manual: manual_rx,
                                feedback: fb_tx,
                                esc: mailbox.clone(),
                                logs: logs.clone(),
                                cancel: cancel.clone(),
                                delay: control_delay,
                                live: live_tx,
                            }
                            .run()
                            .instrument(tracing::info_span!("controller")),
                        );
                        let estimator = EstimatorTask {
                            core: estimator_core,
                            gps,
                            gps_live,
                            frames: frame_rx,
                            feedback: fb_rx,
                            estimates: est_tx,
                            esc: mailbox,
                            esc_status,
                            logs,
                            beats,
                            cancel: cancel.clone(),
                        }
                        .run()
                        .instrument(tracing::info_span!("estimator"))
                        .await;
                        // The estimator ends when frames stop or on cancel: end the run.
                        cancel.cancel();
                        if let Ok(Err(e)) = reader.await {
                            tracing::warn!("IMU read error: {e}");
                        }
                        let controller = controller.await.unwrap_or_default();
                        Ok((estimator?, controller))
                    })
                },
            )
            .context("cannot start the control thread")?
    };

    // Signals: the first stops the motors and ends the run; a second exits at once.
    if opts.handle_signals {
        tokio::spawn(handle_signals(mailbox.clone(), cancel.clone()));
    }

    // The console socket.
    let console_drops = Arc::new(std::sync::atomic::AtomicU64::new(0));
    if !cfg.console.socket.as_os_str().is_empty() {
        let stats: crate::console::StatsFn = {
            let imu = imu_stats.clone();
            let esc = esc_status.clone();
            let wd = wd_status.clone();
            let logs = logs.clone();
            let live = live_rx.clone();
            let beats = beats.clone();
            Arc::new(move || console_stats(&beats, &imu, &esc, &wd, &logs, &live))
        };
        let path = cfg.console.socket.clone();
        let (tx, drops, cancel) = (manual_tx.clone(), console_drops.clone(), cancel.clone());
        tokio::spawn(async move {
            if let Err(e) = crate::console::serve(path.clone(), stats, tx, drops, cancel).await {
                tracing::error!("console socket {}: {e}", path.display());
            }
        });
    }

    // systemd: ready once the IMU delivers frames (the devices are open and talking), then
    // watchdog pings only while the internal watchdog is healthy.
    let notifier = crate::hw::notify::Notifier::from_env().map(Arc::new);
    if let Some(n) = notifier.clone() {
        tokio::spawn(notify_systemd(
            n,
            imu_stats.clone(),
            wd_status.clone(),
            beats.clone(),
            cancel.clone(),
        ));
    }

    cancel.cancelled().await;
    if let Some(n) = &notifier {
        n.send("STOPPING=1");
    }
    // Motors first: zero and disable, then wait for the writer to finish.
    mailbox.shutdown();
    wd_status.stop();
    let _ = tokio::task::spawn_blocking(move || wd_thread.join()).await;
    let esc_joined = tokio::task::spawn_blocking(move || esc_thread.join()).await;
    if !matches!(esc_joined, Ok(Ok(()))) {
        tracing::error!("the ESC writer thread did not end cleanly");
    }
    let control = tokio::task::spawn_blocking(move || control_thread.join()).await;
    let (est, ctl, error) = match control {
        Ok(Ok(Ok((e, c)))) => (e, c, None),
        Ok(Ok(Err(e))) => (
            EstimatorReport::default(),
            ControllerReport::default(),
            Some(format!("{e:#}")),
        ),
        _ => (
            EstimatorReport::default(),
            ControllerReport::default(),
            Some("the control thread panicked".to_string()),
        ),
    };
    if let Some(e) = &error {
        logs.err(format!("error: {e}"));
        tracing::error!("{e}");
    }
    let latencies_us = esc_status
        .latencies_us
        .lock()
        .map(|l| l.clone())
        .unwrap_or_default();
    let mut summary = FlySummary {
        run_dir: run_dir.clone(),
        frames: imu_stats.frames.load(Ordering::Relaxed),
        steps: est.steps,
        discarded_bytes: imu_stats.discarded_bytes.load(Ordering::Relaxed),
        rejected_frames: imu_stats.rejected_frames.load(Ordering::Relaxed),
        dropped_frames: imu_stats.dropped_frames.load(Ordering::Relaxed),
        late_feedback: est.late_feedback,
        ekf_errors: est.ekf_errors,
        gps_updates: est.gps_updates,
        gpsd_connects: gps_stats.connects.load(Ordering::Relaxed),
        gpsd_disconnects: gps_stats.disconnects.load(Ordering::Relaxed),
        gpsd_fixes: gps_stats.fixes.load(Ordering::Relaxed),
        saturated_commands: ctl.saturated,
        esc_writes: esc_status.writes.load(Ordering::Relaxed),
        esc_failed_writes: esc_status.failed_writes.load(Ordering::Relaxed),
        esc_commands: esc_status.commands.load(Ordering::Relaxed),
        esc_stop_reason: esc_status.stop_reason(),
        log_drops: logs.dropped(),
        log_records: [0; 7],
        latencies_us,
        deadline_misses: wd_status.deadline_misses.load(Ordering::Relaxed),
        halt: wd_status.halt(),
        error,
    };
    // The drop counts so far go into err.log itself; then the loggers drain and flush.
    for (i, name) in STREAMS.iter().enumerate() {
        if summary.log_drops[i] > 0 {
            logs.err(format!(
                "log stream {name}: {} records dropped",
                summary.log_drops[i]
            ));
        }
    }
    logs.err(format!(
        "run ended: {} frames, {} steps, ESCs stopped: {}",
        summary.frames,
        summary.steps,
        summary
            .esc_stop_reason
            .as_deref()
            .unwrap_or("never started")
    ));
    drop(logs);
    drop(manual_tx);
    for h in logger_handles {
        match h.await {
            Ok(Ok(rep)) => {
                if let Some(i) = STREAMS.iter().position(|s| *s == rep.stream) {
                    summary.log_records[i] = rep.records;
                }
            }
            Ok(Err(e)) => tracing::error!("a logger failed: {e}"),
            Err(e) => tracing::error!("a logger task failed: {e}"),
        }
    }
    Ok(summary)
}

/// The console's statistics line: latency histogram, deadline misses, log drops, the current
/// estimate and motor speeds.
fn console_stats(
    beats: &Heartbeats,
    imu: &ImuStats,
    esc: &EscStatus,
    wd: &WatchdogStatus,
    logs: &crate::tasks::logger::LogHub,
    live: &watch::Receiver<Option<crate::tasks::controller::Live>>,
) -> String {
    // Latency histogram of the last second's commands (at most 100), in buckets of 100 µs.
    let mut hist = [0u32; 6];
    if let Ok(l) = esc.latencies_us.lock() {
        for &v in l.iter().rev().take(100) {
            hist[(v as usize / 100).min(5)] += 1;
        }
    }
    let mut s = format!(
        "stats t={:.1}s frames={} deadline_misses={} log_drops={} latency_us[<100,<200,<300,<400,<500,>=500]={:?}",
        beats.us(Instant::now()) as f64 / 1e6,
        imu.frames.load(Ordering::Relaxed),
        wd.deadline_misses.load(Ordering::Relaxed),
        logs.dropped().iter().sum::<u64>(),
        hist
    );
    if let Some(l) = *live.borrow() {
        let _ = std::fmt::Write::write_fmt(
            &mut s,
            format_args!(
                " step={} z={:.3} setpoint_z={:.2} roll={:+.3} pitch={:+.3} yaw={:+.3} w=[{:.1}, {:.1}, {:.1}, {:.1}]",
                l.step,
                l.x[2],
                l.setpoint_z_m,
                l.x[3],
                l.x[4],
                l.x[5],
                l.w_rad_s[0],
                l.w_rad_s[1],
                l.w_rad_s[2],
                l.w_rad_s[3]
            ),
        );
    }
    if let Some(h) = wd.halt() {
        let _ = std::fmt::Write::write_fmt(&mut s, format_args!(" HALT={}", h.trip.reason.name()));
    }
    s
}

/// READY=1 after the first IMU frame; WATCHDOG=1 every half `WatchdogSec` while the internal
/// watchdog checks and has not tripped; the pings stop for good at a trip.
async fn notify_systemd(
    n: Arc<crate::hw::notify::Notifier>,
    imu: Arc<ImuStats>,
    wd: Arc<WatchdogStatus>,
    beats: Arc<Heartbeats>,
    cancel: CancellationToken,
) {
    let poll = Duration::from_millis(10);
    while imu.frames.load(Ordering::Relaxed) == 0 {
        tokio::select! {
            _ = cancel.cancelled() => return,
            _ = tokio::time::sleep(poll) => {}
        }
    }
    n.send("READY=1\nSTATUS=IMU frames arriving; flying");
    let Some(every) = crate::hw::notify::watchdog_interval() else {
        return;
    };
    loop {
        tokio::select! {
            _ = cancel.cancelled() => return,
            _ = tokio::time::sleep(every) => {}
        }
        if let Some(h) = wd.halt() {
            n.send(&format!("STATUS=halted: {}", h.trip.reason.name()));
            return;
        }
        let now_us = beats.us(Instant::now());
        let checked_us = wd.last_check_us.load(Ordering::Relaxed);
        // A watchdog that has not checked for 100 ms is not healthy either.
        if now_us - checked_us < 100_000 {
            n.send("WATCHDOG=1");
        }
    }
}

/// Shuts the ESC writer down (zero, disable, end) when dropped; idempotent.
struct StopEscOnDrop(Arc<EscMailbox>);

impl Drop for StopEscOnDrop {
    fn drop(&mut self) {
        self.0.shutdown();
    }
}

/// Reads the original's manual-mode keys (spec 5.2) from stdin, one byte at a time.
async fn read_keys(tx: mpsc::Sender<ManualCommand>, cancel: CancellationToken) {
    use tokio::io::AsyncReadExt;
    let mut stdin = tokio::io::stdin();
    let mut byte = [0u8; 1];
    loop {
        let n = tokio::select! {
            _ = cancel.cancelled() => return,
            r = stdin.read(&mut byte) => match r {
                Ok(n) => n,
                Err(_) => return,
            },
        };
        if n == 0 {
            return;
        }
        if let Some(cmd) = ManualCommand::from_key(byte[0])
            && tx.send(cmd).await.is_err()
        {
            return;
        }
    }
}

/// SIGINT/SIGTERM: the first zeroes and disables the motors and ends the run; a second exits.
async fn handle_signals(mailbox: Arc<EscMailbox>, cancel: CancellationToken) {
    use tokio::signal::unix::{SignalKind, signal};
    let (Ok(mut int), Ok(mut term)) = (
        signal(SignalKind::interrupt()),
        signal(SignalKind::terminate()),
    ) else {
        tracing::error!("cannot install signal handlers");
        return;
    };
    for n in 0..2 {
        tokio::select! {
            _ = int.recv() => {}
            _ = term.recv() => {}
        }
        if n == 0 {
            tracing::info!("signal: stopping the motors and ending the run");
            mailbox.shutdown();
            cancel.cancel();
        } else {
            tracing::warn!("second signal: exiting now");
            std::process::exit(130);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_stamps() {
        assert_eq!(utc_stamp(0), "19700101-000000");
        assert_eq!(utc_stamp(1_327_662_538), "20120127-110858");
        assert_eq!(utc_stamp(951_782_400), "20000229-000000");
    }

    #[test]
    fn run_dirs_are_unique_in_the_same_second() {
        let d = tempfile::tempdir().unwrap();
        let dirs: Vec<PathBuf> = (0..5).map(|_| create_run_dir(d.path()).unwrap()).collect();
        let mut names: Vec<_> = dirs
            .iter()
            .map(|p| p.file_name().unwrap().to_owned())
            .collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), 5);
    }
}
