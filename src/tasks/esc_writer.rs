//! ESC writer: the last line of defence, on its own OS thread (the I2C ioctls block).
//!
//! In: start request, motor commands (newest wins), halt and shutdown, through [`EscMailbox`].
//! Out: I2C transactions on the [`EscBus`]; [`EscStatus`] counters and phase.
//! Rate: re-sends the last speeds every `resend_ms` (2 ms); wakes at once on a new command.
//! Ends: on shutdown, after writing zero to every ESC and disabling them all (retried until
//! each acknowledged, or `watchdog.halt_retry_ms` ran out).
//!
//! The process boots with the ESCs disabled. Start: enable all, then the driver's saw-tooth
//! start-up ramp (spec 6.4), then idle (I2C 50) until flight commands arrive. A flight command
//! older than `command_timeout` or not finite, a halt, or shutdown: zero, then disable (the
//! disable is attempted even when writes keep failing), written again until every ESC
//! acknowledged both or the retry time ran out; no request is taken meanwhile. A failed write
//! is a missed ack: counted, with the run of consecutive failures exposed for the watchdog.

pub use crate::core::esc::EscPhase;
use crate::core::esc::{Cycle, CycleKind, CycleRunner, EscDriver, EscTiming, StopOutcome};
use crate::core::motor::MotorMap;
use crate::hw::esc_bus::EscBus;
use crate::tasks::ESC_WRITER_PRIORITY;
use crate::tasks::heartbeats::{Event, Heartbeats};
use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// A flight command: motor speeds and when the frame that produced it arrived.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorCommand {
    pub w_rad_s: [f64; 4],
    pub frame_at: Instant,
}

#[derive(Debug, Default)]
struct Requests {
    start: bool,
    command: Option<MotorCommand>,
    new_command: bool,
    halt: Option<String>,
    shutdown: bool,
}

/// The writer's inbox: newest command wins; start, halt and shutdown are latched.
#[derive(Debug, Default)]
pub struct EscMailbox {
    req: Mutex<Requests>,
    wake: Condvar,
}

impl EscMailbox {
    fn with<R>(&self, f: impl FnOnce(&mut Requests) -> R) -> R {
        // A poisoned lock means a writer thread panicked; the requests are still plain data.
        let mut g = self.req.lock().unwrap_or_else(|p| p.into_inner());
        let r = f(&mut g);
        self.wake.notify_all();
        r
    }

    /// Enable the ESCs and run the start-up ramp.
    pub fn start(&self) {
        self.with(|r| r.start = true);
    }

    pub fn command(&self, c: MotorCommand) {
        self.with(|r| {
            r.command = Some(c);
            r.new_command = true;
        });
    }

    /// Zero and disable now; `reason` is recorded.
    pub fn halt(&self, reason: &str) {
        self.with(|r| {
            if r.halt.is_none() {
                r.halt = Some(reason.to_string());
            }
        });
    }

    /// [`EscMailbox::halt`] unless the inbox is locked (the panic hook must not wait).
    fn try_halt(&self, reason: &str) {
        if let Ok(mut r) = self.req.try_lock() {
            if r.halt.is_none() {
                r.halt = Some(reason.to_string());
            }
            drop(r);
            self.wake.notify_all();
        }
    }

    /// Zero, disable and end the writer thread.
    pub fn shutdown(&self) {
        self.with(|r| r.shutdown = true);
    }
}

/// The ESC writers of the runs in this process, for the panic hook.
static RUNS: Mutex<Vec<std::sync::Weak<EscMailbox>>> = Mutex::new(Vec::new());

/// From now on a panic anywhere in the process — a flight thread, a task, a logger — halts
/// `mailbox`'s motors before the panic is even reported: the default report of a panic
/// (a backtrace) can take longer than the watchdog's limits. Installed once per process.
pub fn halt_on_any_panic(mailbox: &Arc<EscMailbox>) {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let report = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            // try_lock: the panicking thread may hold a lock; the guards halt then.
            if let Ok(runs) = RUNS.try_lock() {
                for m in runs.iter().filter_map(std::sync::Weak::upgrade) {
                    m.try_halt("panic");
                }
            }
            report(info);
        }));
    });
    let mut runs = RUNS.lock().unwrap_or_else(|p| p.into_inner());
    runs.retain(|w| w.strong_count() > 0);
    runs.push(Arc::downgrade(mailbox));
}

/// Held by every flight thread and control task: dropped during a panic (the unwinding of the
/// release profile), it halts the motors at once with reason "panic" and ends the run, before
/// anything else is torn down.
pub struct HaltOnPanic {
    pub mailbox: Arc<EscMailbox>,
    pub cancel: tokio_util::sync::CancellationToken,
}

impl Drop for HaltOnPanic {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.mailbox.halt("panic");
            self.cancel.cancel();
        }
    }
}

/// Counters and phase, readable from any thread.
#[derive(Debug, Default)]
pub struct EscStatus {
    phase: AtomicU8,
    pub writes: AtomicU64,
    pub failed_writes: AtomicU64,
    /// Flight commands written.
    pub commands: AtomicU64,
    /// Commands refused as stale or not finite.
    pub refused_commands: AtomicU64,
    /// Why the ESCs were stopped, once they were.
    pub stop_reason: Mutex<Option<String>>,
    /// Frame-arrival → ESC-write latency of each flight command, µs (newest last).
    pub latencies_us: Mutex<Vec<u32>>,
    /// How the stop ended (confirmed or not, and when), once it has.
    stop_outcome: Mutex<Option<StopOutcome>>,
    /// The ESCs that did not acknowledge the last probe while disabled, bit m = motor m
    /// (the writer probes as it starts).
    silent: AtomicU8,
}

impl EscStatus {
    pub fn phase(&self) -> EscPhase {
        match self.phase.load(Ordering::SeqCst) {
            0 => EscPhase::Disabled,
            1 => EscPhase::Ramping,
            2 => EscPhase::Running,
            _ => EscPhase::Stopped,
        }
    }

    fn set_phase(&self, p: EscPhase) {
        self.phase.store(p as u8, Ordering::SeqCst);
    }

    pub fn stop_reason(&self) -> Option<String> {
        self.stop_reason.lock().ok().and_then(|g| g.clone())
    }

    /// The addresses that did not acknowledge the last probe (the pre-arm check).
    pub fn silent_addresses(&self, addresses: &[u8; 4]) -> Vec<u8> {
        crate::core::esc::silent_addresses(self.silent.load(Ordering::Relaxed), addresses)
    }

    /// How the stop ended, once it has: every ESC acknowledged it, or the retries ran out.
    pub fn stop_outcome(&self) -> Option<StopOutcome> {
        self.stop_outcome.lock().ok().and_then(|g| *g)
    }
}

/// Latency samples kept (about 2.8 hours of flight at 100 Hz).
const MAX_LATENCY_SAMPLES: usize = 1_000_000;

/// Writer settings.
#[derive(Debug, Clone, Copy)]
pub struct EscParams {
    pub map: MotorMap,
    pub timing: EscTiming,
}

struct Writer {
    bus: Box<dyn EscBus>,
    params: EscParams,
    status: Arc<EscStatus>,
    beats: Arc<Heartbeats>,
    runner: CycleRunner,
}

impl Writer {
    /// Executes the driver's cycles on the bus through the one write loop of every mode, then
    /// publishes the counts, the watchdog's events, the stop time and the command latency.
    fn execute(
        &mut self,
        driver: &mut EscDriver,
        cycles: &mut Vec<(CycleKind, Cycle)>,
        command_frame_at: Option<Instant>,
    ) {
        let (bus, beats, status) = (&mut self.bus, &self.beats, &self.status);
        self.runner.execute(
            driver,
            cycles,
            |addr, reg, value| bus.write_byte_data(addr, reg, value),
            || beats.us(Instant::now()),
            |done, first_error| {
                if let Some(e) = first_error {
                    tracing::warn!("{e}");
                }
                for e in done.watchdog_events() {
                    beats.report(e);
                }
                if let (CycleKind::Command, Some(frame_at)) = (done.kind, command_frame_at) {
                    record_command(status, beats, frame_at, done.at_us);
                }
            },
        );
        if let Some(o) = driver.stop_outcome()
            && let Ok(mut g) = self.status.stop_outcome.lock()
        {
            g.get_or_insert(o);
        }
        self.status
            .silent
            .store(driver.silent_mask(), Ordering::Relaxed);
        self.status
            .writes
            .store(self.runner.writes, Ordering::Relaxed);
        self.status
            .failed_writes
            .store(self.runner.failed_writes, Ordering::Relaxed);
    }
}

/// A flight command written at `written_us`: the watchdog's deadline event and the latency.
fn record_command(status: &EscStatus, beats: &Heartbeats, frame_at: Instant, written_us: i64) {
    let frame_us = beats.us(frame_at);
    beats.report(Event::Command {
        frame_us,
        written_us,
    });
    status.commands.fetch_add(1, Ordering::Relaxed);
    let latency = (written_us - frame_us).clamp(0, i64::from(u32::MAX)) as u32;
    if let Ok(mut l) = status.latencies_us.lock()
        && l.len() < MAX_LATENCY_SAMPLES
    {
        l.push(latency);
    }
}

/// Starts the writer thread. It owns the bus; it ends after shutdown.
pub fn spawn(
    bus: Box<dyn EscBus>,
    params: EscParams,
    mailbox: Arc<EscMailbox>,
    status: Arc<EscStatus>,
    beats: Arc<Heartbeats>,
    realtime: bool,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    crate::tasks::spawn_thread("esc_writer", realtime, ESC_WRITER_PRIORITY, move || {
        run(
            Writer {
                bus,
                params,
                status,
                beats,
                runner: CycleRunner::default(),
            },
            &mailbox,
        )
    })
}

enum Wake {
    Shutdown,
    Halt(String),
    Start,
    Command(MotorCommand),
    Tick,
}

/// Waits for a request or until `deadline`.
fn wait(mailbox: &EscMailbox, deadline: Option<Instant>, accept_start: bool) -> Wake {
    let mut g = mailbox.req.lock().unwrap_or_else(|p| p.into_inner());
    loop {
        if g.shutdown {
            return Wake::Shutdown;
        }
        if let Some(h) = g.halt.clone() {
            return Wake::Halt(h);
        }
        if accept_start && g.start {
            g.start = false;
            return Wake::Start;
        }
        if g.new_command {
            g.new_command = false;
            if let Some(c) = g.command {
                return Wake::Command(c);
            }
        }
        match deadline {
            None => g = mailbox.wake.wait(g).unwrap_or_else(|p| p.into_inner()),
            Some(d) => {
                let now = Instant::now();
                if now >= d {
                    return Wake::Tick;
                }
                g = mailbox
                    .wake
                    .wait_timeout(g, d - now)
                    .unwrap_or_else(|p| p.into_inner())
                    .0;
            }
        }
    }
}

fn run(mut w: Writer, mailbox: &EscMailbox) {
    let mut driver = EscDriver::new(w.params.map, w.params.timing);
    let mut cycles = Vec::with_capacity(8);
    w.status.set_phase(EscPhase::Disabled);
    loop {
        let deadline = driver
            .next_wake_us()
            .map(|us| w.beats.start() + Duration::from_micros(us.max(0) as u64));
        let wake = wait(mailbox, deadline, driver.phase() == EscPhase::Disabled);
        let now_us = w.beats.us(Instant::now());
        let mut frame_at = None;
        match wake {
            Wake::Shutdown => {
                driver.stop("shutdown", now_us, &mut cycles);
                return settle_stop(&mut w, &mut driver, &mut cycles);
            }
            Wake::Halt(reason) => driver.stop(&reason, now_us, &mut cycles),
            Wake::Start => driver.start(now_us),
            Wake::Command(c) => {
                if c.w_rad_s.iter().any(|v| !v.is_finite()) {
                    w.status.refused_commands.fetch_add(1, Ordering::Relaxed);
                }
                frame_at = Some(c.frame_at);
                driver.command(&c.w_rad_s, w.beats.us(c.frame_at), now_us, &mut cycles);
            }
            Wake::Tick => {}
        }
        let was_running = driver.phase() == EscPhase::Running;
        driver.poll(now_us, &mut cycles);
        if was_running && driver.stop_reason() == Some("stale motor command") {
            w.status.refused_commands.fetch_add(1, Ordering::Relaxed);
        }
        w.execute(&mut driver, &mut cycles, frame_at);
        w.finish(&driver);
        if driver.phase() == EscPhase::Stopped {
            settle_stop(&mut w, &mut driver, &mut cycles);
            return park_until_shutdown(mailbox);
        }
    }
}

/// A stop is written again until every ESC acknowledged it or its retry time ran out; no
/// request can interrupt it (a halt or a shutdown during it asks for the same stop).
fn settle_stop(w: &mut Writer, driver: &mut EscDriver, cycles: &mut Vec<(CycleKind, Cycle)>) {
    w.execute(driver, cycles, None);
    while driver.stop_outcome().is_none() {
        let Some(at_us) = driver.next_wake_us() else {
            break;
        };
        let at = w.beats.start() + Duration::from_micros(at_us.max(0) as u64);
        std::thread::sleep(at.saturating_duration_since(Instant::now()));
        driver.poll(w.beats.us(Instant::now()), cycles);
        w.execute(driver, cycles, None);
    }
    w.finish(driver);
    if let Some(o) = driver.stop_outcome()
        && !o.confirmed()
    {
        tracing::error!(
            unconfirmed = ?o.unconfirmed_addresses(),
            "ESC stop not acknowledged by every ESC within the retry time"
        );
    }
}

impl Writer {
    /// Publishes the driver's phase (and why it stopped).
    fn finish(&mut self, driver: &EscDriver) {
        let phase = driver.phase();
        if phase != self.status.phase() {
            match phase {
                EscPhase::Running => tracing::info!("ESC start-up ramp done; idling"),
                EscPhase::Stopped => tracing::info!(
                    reason = driver.stop_reason().unwrap_or(""),
                    "ESCs zeroed and disabled"
                ),
                EscPhase::Disabled | EscPhase::Ramping => {}
            }
        }
        if let Some(r) = driver.stop_reason()
            && let Ok(mut g) = self.status.stop_reason.lock()
            && g.is_none()
        {
            *g = Some(r.to_string());
        }
        self.status.set_phase(phase);
    }
}

/// After a stop the writer writes nothing more; it waits for shutdown to end the thread.
fn park_until_shutdown(mailbox: &EscMailbox) {
    loop {
        if let Wake::Shutdown = wait(mailbox, None, false) {
            return;
        }
        // Halts and commands after a stop are ignored: the motors stay off.
        let mut g = mailbox.req.lock().unwrap_or_else(|p| p.into_inner());
        g.new_command = false;
        g.halt = None;
    }
}
