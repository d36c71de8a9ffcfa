//! ESC writer: the last line of defence, on its own OS thread (the I2C ioctls block).
//!
//! In: start request, motor test, motor commands (newest wins), halt (the watchdog's, a
//! disarm's, the pilot's kill switch) and shutdown, through [`EscMailbox`].
//! Out: I2C transactions on the [`EscBus`]; [`EscStatus`] counters and phase.
//! Rate: re-sends the last speeds every `resend_ms` (2 ms); wakes at once on a new command.
//! Ends: on shutdown, after writing zero to every ESC and disabling them all (retried until
//! each acknowledged, or `watchdog.halt_retry_ms` ran out).
//!
//! The process boots with the ESCs disabled. Start: enable all, then the driver's saw-tooth
//! start-up ramp (spec 6.4), then idle (I2C 50) until flight commands arrive. A flight command
//! older than `command_timeout` or not finite, a halt, or shutdown: zero, then disable (the
//! disable is attempted even when writes keep failing), written again until every ESC
//! acknowledged both or the retry time ran out; no request is taken meanwhile. A disarm's,
//! a motor test's or the kill switch's stop that every ESC acknowledged leaves the writer
//! probing until the next flight's start (the same enable and ramp); every other stop is
//! final. Disarmed, a motor test spins one
//! ESC alone for its time, then stops as a disarm does. A failed write is a missed ack:
//! counted, with the run of consecutive failures exposed for the watchdog.

pub use crate::core::esc::EscPhase;
use crate::core::esc::{
    Cycle, CycleKind, CycleRunner, EscDriver, EscTiming, MotorTest, StopOutcome, StopReason,
};
use crate::core::motor::MotorMap;
use crate::hw::esc_bus::EscBus;
use crate::tasks::heartbeats::{Event, Heartbeats};
use crate::tasks::host_stall::StallWatch;
use crate::tasks::latency::{LatencyLog, Stamps};
use crate::tasks::{Cpu, ESC_WRITER_PRIORITY};
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// A flight command: motor speeds and when its frame arrived, its estimate and it were made.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorCommand {
    pub w_rad_s: [f64; 4],
    pub stamps: Stamps,
}

#[derive(Debug, Default)]
struct Requests {
    start: bool,
    /// A motor test not yet taken (a newer one replaces it).
    test: Option<MotorTest>,
    command: Option<MotorCommand>,
    new_command: bool,
    halt: Option<StopReason>,
    shutdown: bool,
}

/// The writer's inbox: newest command wins; start, halt and shutdown wait until the writer
/// takes them (a halt drops a start not yet taken).
///
/// Waking a sleeping thread costs tens of microseconds on this kind of machine (more on a
/// virtual one), so the command's hand-off avoids it: when a frame has been decoded and a
/// command will follow, [`EscMailbox::expect_command`] wakes the writer while the estimate and
/// the control law are still being computed, and the writer then spins on `seq` until the
/// command lands (at most `SPIN_LIMIT`). A request notifies the condition variable only when the
/// writer is parked on it, so the command itself costs no system call.
#[derive(Debug, Default)]
pub struct EscMailbox {
    req: Mutex<Requests>,
    wake: Condvar,
    /// Bumped with every request; the spinning writer watches it.
    seq: AtomicU64,
    /// The writer is blocked on `wake` (set and cleared under `req`'s lock).
    parked: AtomicBool,
    /// A command is on its way: the writer spins for it instead of sleeping.
    expect: AtomicBool,
}

/// How long the writer spins for an expected command before it sleeps again: well above the
/// decode → command time (tens of µs), well below the 10 ms period.
const SPIN_LIMIT: Duration = Duration::from_micros(1500);

impl EscMailbox {
    fn with<R>(&self, f: impl FnOnce(&mut Requests) -> R) -> R {
        // A poisoned lock means a writer thread panicked; the requests are still plain data.
        let mut g = self.req.lock().unwrap_or_else(|p| p.into_inner());
        let r = f(&mut g);
        self.seq.fetch_add(1, Ordering::SeqCst);
        drop(g);
        // Read after the lock is released: a writer that parked before we took the lock is
        // seen here; one that parks after it sees the request before it sleeps.
        if self.parked.load(Ordering::SeqCst) {
            self.wake.notify_all();
        }
        r
    }

    /// A frame was decoded and a command will follow: wake the writer now, so that it is
    /// spinning, not asleep, when the command lands.
    pub fn expect_command(&self) {
        self.expect.store(true, Ordering::SeqCst);
        let g = self.req.lock().unwrap_or_else(|p| p.into_inner());
        let parked = self.parked.load(Ordering::SeqCst);
        drop(g);
        if parked {
            self.wake.notify_all();
        }
    }

    /// Spins until a request arrives after `seen` (true) or `until` passes (false).
    fn spin_for_request(&self, seen: u64, until: Instant) -> bool {
        loop {
            if self.seq.load(Ordering::SeqCst) != seen {
                return true;
            }
            if Instant::now() >= until {
                return false;
            }
            for _ in 0..64 {
                std::hint::spin_loop();
            }
        }
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

    /// Spin one motor alone (a motor test), from disabled or between flights.
    pub fn test_motor(&self, test: MotorTest) {
        self.with(|r| r.test = Some(test));
    }

    /// Zero and disable now; `reason` is recorded. A start or a motor test not yet taken is
    /// dropped: a disarm right after an arm leaves the motors off.
    pub fn halt(&self, reason: StopReason) {
        self.with(|r| {
            r.start = false;
            r.test = None;
            r.halt = Some(stronger(r.halt, reason));
        });
    }

    /// [`EscMailbox::halt`] unless the inbox is locked (the panic hook must not wait).
    fn try_halt(&self, reason: StopReason) {
        if let Ok(mut r) = self.req.try_lock() {
            r.start = false;
            r.test = None;
            r.halt = Some(stronger(r.halt, reason));
            self.seq.fetch_add(1, Ordering::SeqCst);
            drop(r);
            self.wake.notify_all();
        }
    }

    /// Zero, disable and end the writer thread.
    pub fn shutdown(&self) {
        self.with(|r| r.shutdown = true);
    }
}

/// The halt that stands when `reason` comes with `waiting` not yet taken: the first, unless
/// it is one the run goes on after (a disarm's, the kill switch's: a held switch sends one
/// every frame) and `reason` is final (the watchdog's, a panic's, the run's end).
fn stronger(waiting: Option<StopReason>, reason: StopReason) -> StopReason {
    match waiting {
        Some(w) if w.on_the_ground() && !reason.on_the_ground() => reason,
        Some(w) => w,
        None => reason,
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
                    m.try_halt(StopReason::Panic);
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
            self.mailbox.halt(StopReason::Panic);
            self.cancel.cancel();
        }
    }
}

/// The ESC writer as the flight's edges (`core::flight::drive`): starts and stops through the
/// mailbox, never waiting; the operator's quit ends the run (the shutdown stops the motors).
pub struct MailboxEscs<'a> {
    pub esc: &'a EscMailbox,
    pub cancel: &'a tokio_util::sync::CancellationToken,
}

impl crate::core::flight::drive::EscEdges for MailboxEscs<'_> {
    fn escs(&mut self, ask: crate::core::flight::drive::EscAsk) {
        use crate::core::flight::drive::EscAsk;
        match ask {
            EscAsk::Start => self.esc.start(),
            EscAsk::Stop(reason) => self.esc.halt(reason),
            EscAsk::TestMotor(test) => self.esc.test_motor(test),
        }
    }

    fn quit(&mut self) {
        self.cancel.cancel();
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
    pub stop_reason: Mutex<Option<StopReason>>,
    /// Frame-arrival → ESC-write latency of the flight commands, and its stages.
    pub latency: LatencyLog,
    /// How the stop ended (confirmed or not, and when), once it has.
    stop_outcome: Mutex<Option<StopOutcome>>,
    /// The ESCs that did not acknowledge the last probe while disabled, bit m = motor m
    /// (the writer probes as it starts).
    silent: AtomicU8,
    /// Start requests the writer has taken (one per flight).
    starts: std::sync::atomic::AtomicU32,
}

impl EscStatus {
    pub fn phase(&self) -> EscPhase {
        match self.phase.load(Ordering::SeqCst) {
            0 => EscPhase::Disabled,
            1 => EscPhase::Ramping,
            2 => EscPhase::Running,
            4 => EscPhase::Testing,
            _ => EscPhase::Stopped,
        }
    }

    fn set_phase(&self, p: EscPhase) {
        self.phase.store(p as u8, Ordering::SeqCst);
    }

    pub fn stop_reason(&self) -> Option<StopReason> {
        self.stop_reason.lock().ok().and_then(|g| *g)
    }

    /// Start requests taken so far; read before [`EscStatus::phase`], the phase is at least
    /// as new as the start counted.
    pub fn starts(&self) -> u32 {
        self.starts.load(Ordering::SeqCst)
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
        command_stamps: Option<Stamps>,
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
                if let (CycleKind::Command, Some(stamps)) = (done.kind, command_stamps) {
                    record_command(status, beats, &stamps, done.at_us);
                }
            },
        );
        if let Some(o) = driver.stop_outcome()
            && let Ok(mut g) = self.status.stop_outcome.lock()
        {
            // The newest: a halt between flights settles the disarm's stop again, later.
            *g = Some(o);
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
fn record_command(status: &EscStatus, beats: &Heartbeats, stamps: &Stamps, written_us: i64) {
    beats.report(Event::Command {
        frame_us: beats.us(stamps.decoded),
        written_us,
    });
    status.commands.fetch_add(1, Ordering::Relaxed);
    let written = beats.start() + Duration::from_micros(written_us.max(0) as u64);
    status.latency.record(stamps, written);
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
    crate::tasks::spawn_thread(
        "esc_writer",
        realtime,
        ESC_WRITER_PRIORITY,
        Cpu::Last,
        move || {
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
        },
    )
}

enum Wake {
    Shutdown,
    Halt(StopReason),
    Start,
    Test(MotorTest),
    Command(MotorCommand),
    Tick,
}

/// Waits for a request or until `deadline`; when `spin` (the ESCs are running) and a command
/// is expected, spins for it instead of sleeping.
fn wait(mailbox: &EscMailbox, deadline: Option<Instant>, accept_start: bool, spin: bool) -> Wake {
    let mut g = mailbox.req.lock().unwrap_or_else(|p| p.into_inner());
    loop {
        mailbox.parked.store(false, Ordering::SeqCst);
        if g.shutdown {
            return Wake::Shutdown;
        }
        // Taken: the driver holds the stop from then on (a disarm's, after which the next
        // flight may start; any other is final).
        if let Some(h) = g.halt.take() {
            return Wake::Halt(h);
        }
        if accept_start && g.start {
            g.start = false;
            g.test = None;
            return Wake::Start;
        }
        if accept_start && let Some(test) = g.test.take() {
            return Wake::Test(test);
        }
        if g.new_command {
            g.new_command = false;
            if let Some(c) = g.command {
                // The command expected, if any, is this one: no spin for it afterwards.
                mailbox.expect.store(false, Ordering::SeqCst);
                return Wake::Command(c);
            }
        }
        let now = Instant::now();
        if deadline.is_some_and(|d| now >= d) {
            return Wake::Tick;
        }
        if spin && mailbox.expect.swap(false, Ordering::SeqCst) {
            let seen = mailbox.seq.load(Ordering::SeqCst);
            drop(g);
            let until = deadline.map_or(now + SPIN_LIMIT, |d| d.min(now + SPIN_LIMIT));
            mailbox.spin_for_request(seen, until);
            g = mailbox.req.lock().unwrap_or_else(|p| p.into_inner());
            continue;
        }
        mailbox.parked.store(true, Ordering::SeqCst);
        match deadline {
            None => g = mailbox.wake.wait(g).unwrap_or_else(|p| p.into_inner()),
            Some(d) => {
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
    // Spinning for a command is only safe on a CPU the control path does not use: without its
    // own CPU (one CPU, no realtime, pinning refused) the writer sleeps until the command.
    let may_spin = crate::tasks::pinned();
    let mut driver = EscDriver::new(w.params.map, w.params.timing);
    let mut cycles = Vec::with_capacity(8);
    w.status.set_phase(EscPhase::Disabled);
    let mut stalls = StallWatch::default();
    let mut previous = Instant::now();
    loop {
        let deadline = driver
            .next_wake_us()
            .map(|us| w.beats.start() + Duration::from_micros(us.max(0) as u64));
        let phase = driver.phase();
        let on_the_ground = matches!(phase, EscPhase::Disabled | EscPhase::Testing);
        let wake = wait(
            mailbox,
            deadline,
            on_the_ground || driver.restartable(),
            may_spin && phase == EscPhase::Running,
        );
        let now = Instant::now();
        let now_us = w.beats.us(now);
        // Late against the previous wake-up too: a stall during the last bus work counts (a
        // slow bus counts as well, within the same budget that bounds every excuse).
        if let Some(due) = deadline.filter(|_| phase == EscPhase::Running) {
            let late_us = now.saturating_duration_since(due.max(previous)).as_micros() as i64;
            if let Some((from_us, to_us)) = stalls.excused(late_us, now_us) {
                driver.excuse_stall(from_us, to_us);
            }
        }
        previous = now;
        let mut stamps = None;
        match wake {
            Wake::Shutdown => {
                driver.stop(StopReason::Shutdown, now_us, &mut cycles);
                return settle_stop(&mut w, &mut driver, &mut cycles);
            }
            Wake::Halt(reason) => driver.stop(reason, now_us, &mut cycles),
            Wake::Start => {
                driver.start(now_us);
                // The restart is published (the last stop cleared) before its first write
                // is reported to the watchdog: a halt from then on waits for its own stop.
                w.finish(&driver);
            }
            Wake::Test(test) => {
                driver.test_motor(test, now_us, &mut cycles);
            }
            Wake::Command(c) => {
                if c.w_rad_s.iter().any(|v| !v.is_finite()) {
                    w.status.refused_commands.fetch_add(1, Ordering::Relaxed);
                }
                stamps = Some(c.stamps);
                let frame_us = w.beats.us(c.stamps.decoded);
                driver.command(&c.w_rad_s, frame_us, now_us, &mut cycles);
            }
            Wake::Tick => {}
        }
        let was_running = driver.phase() == EscPhase::Running;
        driver.poll(now_us, &mut cycles);
        if was_running && driver.stop_reason() == Some(StopReason::StaleCommand) {
            w.status.refused_commands.fetch_add(1, Ordering::Relaxed);
        }
        w.execute(&mut driver, &mut cycles, stamps);
        w.finish(&driver);
        if driver.phase() == EscPhase::Stopped && driver.stop_outcome().is_none() {
            settle_stop(&mut w, &mut driver, &mut cycles);
        }
        // A disarm's stop waits for the next flight's start, probing the ESCs; any other
        // stop is final.
        if driver.phase() == EscPhase::Stopped && !driver.restartable() {
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
    /// Publishes the driver's phase (and why it stopped); a new flight's start clears the
    /// last stop, and its count is published last (a reader that sees it sees the phase
    /// after it).
    fn finish(&mut self, driver: &EscDriver) {
        let phase = driver.phase();
        let starts = driver.starts();
        let restarted = starts != self.status.starts.load(Ordering::SeqCst);
        // A flight's start, or a motor test's: the last stop is not this one's (a halt
        // waits for its own stop's outcome).
        let testing = phase == EscPhase::Testing && self.status.phase() != EscPhase::Testing;
        if restarted || testing {
            if let Ok(mut g) = self.status.stop_reason.lock() {
                *g = None;
            }
            if let Ok(mut g) = self.status.stop_outcome.lock() {
                *g = None;
            }
        }
        if phase != self.status.phase() {
            match phase {
                EscPhase::Running => tracing::info!("ESC start-up ramp done; idling"),
                EscPhase::Stopped => tracing::info!(
                    reason = driver.stop_reason().map_or("", StopReason::name),
                    "ESCs zeroed and disabled"
                ),
                EscPhase::Testing => {
                    if let Some(t) = driver.motor_test() {
                        tracing::info!(
                            motor = t.motor,
                            value = t.value,
                            seconds = t.duration_us as f64 / 1e6,
                            "motor test: one motor alone"
                        );
                    }
                }
                EscPhase::Disabled | EscPhase::Ramping => {}
            }
        }
        // The driver's own: a halt between flights makes the disarm's stop the halt's.
        if let Some(r) = driver.stop_reason()
            && let Ok(mut g) = self.status.stop_reason.lock()
        {
            *g = Some(r);
        }
        self.status.set_phase(phase);
        if restarted {
            tracing::info!(flight = starts, "ESC start-up ramp");
            self.status.starts.store(starts, Ordering::SeqCst);
        }
    }
}

/// After a final stop (any but a confirmed disarm's) the writer writes nothing more; it
/// waits for shutdown to end the thread.
fn park_until_shutdown(mailbox: &EscMailbox) {
    loop {
        if let Wake::Shutdown = wait(mailbox, None, false, false) {
            return;
        }
        // Halts and commands after a stop are ignored: the motors stay off.
        let mut g = mailbox.req.lock().unwrap_or_else(|p| p.into_inner());
        g.new_command = false;
        g.halt = None;
    }
}
