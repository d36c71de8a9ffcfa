//! The ESC writer's decisions as a pure state machine: when to enable, the start-up ramp,
//! re-sending the last speeds, trims, and when to write zero and disable (spec 6.3, 6.4) —
//! a stop retried until every ESC acknowledged its zero and its disable, or the retry time
//! ran out (a refused write may mean a spinning motor).
//! The thread in `tasks::esc_writer` and the simulator's lock-step loop both drive it; it
//! returns write cycles (four SMBus writes each, one per ESC) and never touches a bus or a clock.

use crate::core::motor::{
    EscAction, I2C_IDLE, I2C_MAX, MotorMap, REG_DISABLE, REG_ENABLE, REG_SPEED, esc_startup_ramp,
    esc_startup_ramp_us, i2c_from_rad_s,
};
use crate::core::watchdog::{Event, Halt, Trip};

/// Where the ESCs are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum EscPhase {
    /// Disabled, waiting for the start request (the process boots here).
    Disabled = 0,
    /// Running the start-up ramp.
    Ramping = 1,
    /// Ramp done; idling or following flight commands.
    Running = 2,
    /// Zero written and disabled.
    Stopped = 3,
    /// A motor test: one ESC enabled and spun alone, disarmed (the others disabled).
    Testing = 4,
}

/// The highest throttle a motor test may ask, % of the ESC's range above idle: enough to
/// see a motor's direction and hear its bearings, well under the thrust that lifts a corner
/// of the vehicle off its feet.
pub const MOTOR_TEST_MAX_PCT: f64 = 30.0;
/// The longest a motor test may run, s (QGroundControl asks 3 s, Mission Planner 2 s).
pub const MOTOR_TEST_MAX_S: f64 = 5.0;

/// A ground station's motor test: one motor spun alone on the ground, disarmed, to check
/// the motor order and each one's direction before a first flight.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MotorTest {
    /// The motor, 0-based in the motor map's order (a ground station's motor 1 is m0).
    pub motor: usize,
    /// Its I2C speed value before its trim.
    pub value: u8,
    /// How long it spins at `value`, µs, after the ESC's start-up ramp.
    pub duration_us: i64,
}

impl MotorTest {
    /// Motor `motor` (0-based) at `throttle_pct` of the range from idle to `I2C_MAX`, for
    /// `duration_s` (the caller bounds both).
    pub fn new(motor: usize, throttle_pct: f64, duration_s: f64) -> Self {
        let span = f64::from(I2C_MAX - I2C_IDLE);
        let above_idle = (throttle_pct.clamp(0.0, 100.0) / 100.0 * span).round() as u8;
        MotorTest {
            motor: motor.min(3),
            value: I2C_IDLE + above_idle,
            duration_us: (duration_s.max(0.0) * 1e6).round() as i64,
        }
    }

    /// From the request to the motor's stop, µs: the ESC's start-up ramp (as for a flight:
    /// the enable wait, then the saw-tooth these ESCs start their motor with), then the spin.
    pub fn total_us(&self) -> i64 {
        esc_startup_ramp_us() as i64 + self.duration_us
    }
}

/// One write to each ESC: (address, register, value).
pub type Cycle = [(u8, u8, u8); 4];

/// What a cycle is, for the caller's bookkeeping.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CycleKind {
    Enable,
    Ramp,
    /// Speeds (idle or a flight command re-sent).
    Speeds,
    /// A new flight command, written at once.
    Command,
    /// Zero speeds, then (the next cycle) disable: the stop.
    StopZero,
    StopDisable,
    /// A disable written to disabled ESCs: do they answer? (the pre-arm check).
    Probe,
    /// A motor test's start: the tested ESC enabled, the others disabled (not the watchdog's
    /// "motors enabled": nothing flies).
    TestEnable,
}

/// The addresses of the motors whose bits are set in `mask`.
pub fn silent_addresses(mask: u8, addresses: &[u8; 4]) -> Vec<u8> {
    (0..4)
        .filter(|m| mask & (1 << m) != 0)
        .map(|m| addresses[m])
        .collect()
}

/// Disabled ESCs are probed this often, µs.
pub const PROBE_PERIOD_US: i64 = 500_000;

/// How a stop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StopOutcome {
    /// The addresses of the ESCs that never acknowledged a zero speed and then a disable, in
    /// motor order; none when the stop was confirmed.
    pub unconfirmed: [Option<u8>; 4],
    /// When the last acknowledgement came (confirmed) or the retries ran out, µs since start.
    pub settled_us: i64,
}

impl StopOutcome {
    /// Every ESC acknowledged a zero speed and then a disable.
    pub fn confirmed(&self) -> bool {
        self.unconfirmed.iter().all(Option::is_none)
    }

    /// The addresses that never confirmed their stop.
    pub fn unconfirmed_addresses(&self) -> Vec<u8> {
        self.unconfirmed.iter().flatten().copied().collect()
    }

    /// The halt `trip` became, with this stop.
    pub fn halt(&self, trip: Trip) -> Halt {
        Halt {
            trip,
            halt_us: self.settled_us,
            unconfirmed: self.unconfirmed,
        }
    }
}

/// A stop being confirmed: which ESCs acknowledged their zero and their disable.
#[derive(Debug, Clone, Copy)]
struct StopRetry {
    zero_acked: [bool; 4],
    disable_acked: [bool; 4],
    next_us: i64,
    deadline_us: i64,
}

/// The driver's timing, µs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EscTiming {
    /// The last speeds are re-sent this often; a refused stop is retried this often.
    pub resend_us: i64,
    /// A flight command older than this is replaced by a stop.
    pub command_timeout_us: i64,
    /// A stop is retried until every ESC acknowledged it, for at most this long.
    pub halt_retry_us: i64,
}

/// Why the ESCs were stopped. [`StopReason::name`] is the one text of each, as err.log, the
/// reports, the flight's abort on stopped ESCs and the commander's disarm show it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// Disarmed on the ground: a landing, a disarm, a failed start-up.
    Disarmed,
    /// A motor test's time ran out.
    MotorTestDone,
    /// The pilot's kill switch: a halt named `kill` from any mode, after which the vehicle
    /// is disarmed and may arm again (the switch off).
    KillSwitch,
    /// The run ends: a signal, a quit, the program's end.
    Shutdown,
    /// A panic somewhere in the process.
    Panic,
    /// A motor command that is not a number.
    NonFiniteCommand,
    /// A flight command older than `esc.command_timeout_ms`.
    StaleCommand,
    /// The watchdog's halt, for its reason.
    Halt(crate::core::watchdog::TripReason),
}

impl StopReason {
    /// A stop that the next flight (or motor test) may follow: a disarm's, a motor test's
    /// end, the kill switch's (the pilot's, unlike the watchdog's halts).
    pub fn on_the_ground(self) -> bool {
        matches!(
            self,
            StopReason::Disarmed | StopReason::MotorTestDone | StopReason::KillSwitch
        )
    }

    pub fn name(self) -> &'static str {
        match self {
            StopReason::Disarmed => "disarmed",
            StopReason::MotorTestDone => "motor test done",
            StopReason::KillSwitch => "kill",
            StopReason::Shutdown => "shutdown",
            StopReason::Panic => "panic",
            StopReason::NonFiniteCommand => "non-finite motor command",
            StopReason::StaleCommand => "stale motor command",
            StopReason::Halt(reason) => reason.name(),
        }
    }
}

impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[derive(Debug, Clone)]
pub struct EscDriver {
    map: MotorMap,
    resend_us: i64,
    command_timeout_us: i64,
    halt_retry_us: i64,
    phase: EscPhase,
    ramp: Vec<(u64, EscAction)>,
    ramp_next: usize,
    ramp_start_us: i64,
    values: [u8; 4],
    next_resend_us: i64,
    /// Arrival of the frame of the newest flight command.
    command_frame_us: Option<i64>,
    /// The writer's last excused stall (`excuse_stall`): not part of a command's age.
    excused_us: Option<(i64, i64)>,
    stop_reason: Option<StopReason>,
    retry: Option<StopRetry>,
    outcome: Option<StopOutcome>,
    /// While disabled: when the next probe is due, and which ESCs acknowledged the last one.
    next_probe_us: i64,
    probe_acked: Option<[bool; 4]>,
    /// Start requests taken, this run (the driver's caller waits for its own to be taken).
    starts: u32,
    /// The motor test under way, and when its motor spins from and until, µs.
    test: Option<(MotorTest, i64, i64)>,
}

impl EscDriver {
    pub fn new(map: MotorMap, timing: EscTiming) -> Self {
        EscDriver {
            map,
            resend_us: timing.resend_us,
            command_timeout_us: timing.command_timeout_us,
            halt_retry_us: timing.halt_retry_us,
            retry: None,
            outcome: None,
            phase: EscPhase::Disabled,
            ramp: esc_startup_ramp().collect(),
            ramp_next: 0,
            ramp_start_us: 0,
            values: [I2C_IDLE; 4],
            next_resend_us: 0,
            command_frame_us: None,
            excused_us: None,
            stop_reason: None,
            next_probe_us: 0,
            probe_acked: None,
            starts: 0,
            test: None,
        }
    }

    /// The addresses that did not acknowledge the last probe (all of them before the first).
    pub fn silent_addresses(&self) -> Vec<u8> {
        silent_addresses(self.silent_mask(), &self.map.addresses)
    }

    /// [`EscDriver::silent_addresses`] as bits in motor order (bit m: motor m silent). While
    /// a stop settles, and after a final one, no ESC can be started: all count as silent
    /// (the pre-arm check refuses an arm).
    pub fn silent_mask(&self) -> u8 {
        if self.phase == EscPhase::Stopped && !self.restartable() {
            return 0b1111;
        }
        let acked = self.probe_acked.unwrap_or([false; 4]);
        (0..4)
            .filter(|&m| !acked[m])
            .fold(0, |mask, m| mask | 1 << m)
    }

    pub fn phase(&self) -> EscPhase {
        self.phase
    }

    pub fn stop_reason(&self) -> Option<StopReason> {
        self.stop_reason
    }

    /// When [`EscDriver::poll`] next has something to do; `None` when only a request can.
    pub fn next_wake_us(&self) -> Option<i64> {
        match self.phase {
            EscPhase::Ramping => self
                .ramp
                .get(self.ramp_next)
                .map(|(at, _)| self.ramp_start_us + *at as i64),
            EscPhase::Running => Some(self.next_resend_us),
            EscPhase::Testing => self.test.map(|(_, from_us, until_us)| {
                let ramp_us = self
                    .ramp
                    .get(self.ramp_next)
                    .map(|(at, _)| self.ramp_start_us + *at as i64);
                ramp_us
                    .unwrap_or(self.next_resend_us.max(from_us))
                    .min(until_us)
            }),
            EscPhase::Stopped if self.restartable() => Some(self.next_probe_us),
            EscPhase::Stopped => self.retry.map(|r| r.next_us.min(r.deadline_us)),
            EscPhase::Disabled => Some(self.next_probe_us),
        }
    }

    /// How the stop ended, once it has: confirmed, or its retries ran out.
    pub fn stop_outcome(&self) -> Option<StopOutcome> {
        self.outcome
    }

    /// Start requests taken so far (one per flight).
    pub fn starts(&self) -> u32 {
        self.starts
    }

    /// Stopped by a disarm, a motor test's end or the pilot's kill switch, and every ESC
    /// acknowledged the stop: a start may follow (the next flight of the run). Every other
    /// stop is final: the watchdog's halt, a bad command, the run's end, or a stop some ESC
    /// never acknowledged (its motor may be spinning).
    pub fn restartable(&self) -> bool {
        self.phase == EscPhase::Stopped
            && self.stop_reason.is_some_and(StopReason::on_the_ground)
            && self.outcome.is_some_and(|o| o.confirmed())
    }

    /// The motor test under way, if one is.
    pub fn motor_test(&self) -> Option<MotorTest> {
        self.test.map(|(t, ..)| t)
    }

    /// Start request: enable and ramp, from `now_us`, from disabled, after a disarm's stop
    /// (the same start-up as the first flight) or during a motor test (the ramp takes every
    /// motor over); ignored otherwise.
    pub fn start(&mut self, now_us: i64) {
        if self.phase != EscPhase::Disabled
            && self.phase != EscPhase::Testing
            && !self.restartable()
        {
            return;
        }
        self.test = None;
        self.starts += 1;
        self.phase = EscPhase::Ramping;
        self.ramp_start_us = now_us;
        self.ramp_next = 0;
        self.values = [I2C_IDLE; 4];
        self.command_frame_us = None;
        self.stop_reason = None;
        self.retry = None;
        self.outcome = None;
    }

    fn speeds(&self, values: &[u8; 4]) -> Cycle {
        self.map.speed_writes(values)
    }

    /// A motor test from `now_us`: the tested ESC enabled and the others disabled at once,
    /// the start-up ramp written to it alone, then its speed (re-sent like a flight's) for
    /// the test's time, then the stop. Taken where a start would be (disabled, after a
    /// disarm's stop) and during another test, which it replaces; false (nothing done)
    /// otherwise.
    pub fn test_motor(
        &mut self,
        test: MotorTest,
        now_us: i64,
        out: &mut Vec<(CycleKind, Cycle)>,
    ) -> bool {
        let startable = matches!(self.phase, EscPhase::Disabled | EscPhase::Testing);
        if !(startable || self.restartable()) || test.motor > 3 {
            return false;
        }
        self.phase = EscPhase::Testing;
        self.stop_reason = None;
        self.retry = None;
        self.outcome = None;
        self.command_frame_us = None;
        let from_us = now_us + esc_startup_ramp_us() as i64;
        self.test = Some((test, from_us, from_us + test.duration_us));
        // The ramp's enable is the test's own first cycle.
        self.ramp_start_us = now_us;
        self.ramp_next = 1;
        self.values = [0; 4];
        self.values[test.motor] = test.value;
        self.next_resend_us = from_us;
        let mut enable = self.map.addresses.map(|a| (a, REG_DISABLE, 0));
        enable[test.motor].1 = REG_ENABLE;
        out.push((CycleKind::TestEnable, enable));
        true
    }

    /// Zero, then disable every ESC, from `now_us`; retried (see [`EscDriver::poll`]) until
    /// each ESC acknowledged both or the retry time ran out; then nothing more.
    pub fn stop(&mut self, reason: StopReason, now_us: i64, out: &mut Vec<(CycleKind, Cycle)>) {
        self.test = None;
        if self.phase == EscPhase::Stopped {
            // Between flights the motors are already off: a halt (or any stop but the run's
            // end) makes the stop final, and is settled by the disarm's confirmed stop, now.
            // A held kill switch asks again every frame: the stop stands as it settled.
            if self.restartable()
                && reason != StopReason::Shutdown
                && self.stop_reason != Some(reason)
            {
                self.stop_reason = Some(reason);
                self.outcome = self.outcome.map(|o| StopOutcome {
                    settled_us: now_us,
                    ..o
                });
            }
            return;
        }
        self.stop_reason = Some(reason);
        if self.phase == EscPhase::Disabled {
            // Never enabled: nothing spins, nothing to write.
            self.phase = EscPhase::Stopped;
            self.outcome = Some(StopOutcome {
                unconfirmed: [None; 4],
                settled_us: now_us,
            });
            return;
        }
        self.phase = EscPhase::Stopped;
        self.retry = Some(StopRetry {
            zero_acked: [false; 4],
            disable_acked: [false; 4],
            next_us: now_us + self.resend_us,
            deadline_us: now_us + self.halt_retry_us,
        });
        self.push_stop(out);
    }

    fn push_stop(&self, out: &mut Vec<(CycleKind, Cycle)>) {
        out.push((CycleKind::StopZero, self.speeds(&[0; 4])));
        out.push((
            CycleKind::StopDisable,
            self.map.addresses.map(|a| (a, REG_DISABLE, 0)),
        ));
    }

    /// A cycle was executed: a stop's acknowledgements are noted, and the stop is confirmed
    /// once every ESC acknowledged a zero and, after it, a disable.
    pub fn on_done(&mut self, done: &CycleDone) {
        if done.kind == CycleKind::Probe {
            self.probe_acked = Some(done.acked);
            return;
        }
        let Some(r) = &mut self.retry else {
            return;
        };
        for m in 0..4 {
            match done.kind {
                CycleKind::StopZero => r.zero_acked[m] |= done.acked[m],
                CycleKind::StopDisable => r.disable_acked[m] |= done.acked[m] && r.zero_acked[m],
                _ => {}
            }
        }
        if r.disable_acked.iter().all(|&a| a) {
            self.settle(done.at_us);
        }
    }

    /// The stop ends: confirmed, or with the ESCs that never acknowledged it named.
    fn settle(&mut self, at_us: i64) {
        let Some(r) = self.retry.take() else {
            return;
        };
        let unconfirmed =
            std::array::from_fn(|m| (!r.disable_acked[m]).then_some(self.map.addresses[m]));
        self.outcome = Some(StopOutcome {
            unconfirmed,
            settled_us: at_us,
        });
        if self.stop_reason.is_some_and(StopReason::on_the_ground) {
            // Between flights the pre-arm check asks again whether each ESC answers: the
            // stop's own acknowledgements are the first answer, probes the next.
            self.probe_acked = Some(r.disable_acked);
            self.next_probe_us = at_us + PROBE_PERIOD_US;
        }
    }

    /// A flight command for the frame that arrived at `frame_us`: written at once when running;
    /// a non-finite speed stops the ESCs instead.
    pub fn command(
        &mut self,
        w_rad_s: &[f64; 4],
        frame_us: i64,
        now_us: i64,
        out: &mut Vec<(CycleKind, Cycle)>,
    ) {
        if self.phase != EscPhase::Running {
            return;
        }
        if w_rad_s.iter().any(|v| !v.is_finite()) {
            return self.stop(StopReason::NonFiniteCommand, now_us, out);
        }
        self.values = w_rad_s.map(i2c_from_rad_s);
        self.command_frame_us = Some(frame_us);
        out.push((CycleKind::Command, self.speeds(&self.values)));
        self.next_resend_us = now_us + self.resend_us;
    }

    /// The writer did not run from `from_us` to `to_us`: the host stalled it, and every
    /// flight thread with it (`tasks::host_stall`). A command's age leaves that span out, as
    /// the watchdog's rules do, whether its frame came before the stall or its command was
    /// taken after it: the control path resumes with the frames that waited meanwhile, and a
    /// stop now would drop a vehicle that has flown through the pause.
    pub fn excuse_stall(&mut self, from_us: i64, to_us: i64) {
        self.excused_us = Some((from_us, to_us));
    }

    /// How long the command for the frame at `frame_us` has been standing at `now_us`, less
    /// an excused stall within that time.
    fn command_age_us(&self, frame_us: i64, now_us: i64) -> i64 {
        let excused_us = self
            .excused_us
            .map_or(0, |(a, b)| (b.min(now_us) - a.max(frame_us)).max(0));
        now_us - frame_us - excused_us
    }

    /// Does what is due at `now_us`: ramp steps, the periodic re-send, the stale-command stop,
    /// the retries of an unconfirmed stop.
    pub fn poll(&mut self, now_us: i64, out: &mut Vec<(CycleKind, Cycle)>) {
        match self.phase {
            EscPhase::Ramping => {
                while let Some(&(at, action)) = self.ramp.get(self.ramp_next) {
                    if self.ramp_start_us + at as i64 > now_us {
                        return;
                    }
                    self.ramp_next += 1;
                    out.push(match action {
                        EscAction::EnableAll => (
                            CycleKind::Enable,
                            self.map.addresses.map(|a| (a, REG_ENABLE, 0)),
                        ),
                        EscAction::SpeedAll(v) => (
                            CycleKind::Ramp,
                            self.map.addresses.map(|a| (a, REG_SPEED, v)),
                        ),
                    });
                }
                // Ramp done: idle from now on.
                self.phase = EscPhase::Running;
                self.next_resend_us = now_us;
                self.poll(now_us, out);
            }
            EscPhase::Running => {
                if let Some(f) = self.command_frame_us
                    && self.command_age_us(f, now_us) > self.command_timeout_us
                {
                    return self.stop(StopReason::StaleCommand, now_us, out);
                }
                if now_us >= self.next_resend_us {
                    out.push((CycleKind::Speeds, self.speeds(&self.values)));
                    self.next_resend_us += self.resend_us;
                    if self.next_resend_us <= now_us {
                        self.next_resend_us = now_us + self.resend_us;
                    }
                }
            }
            EscPhase::Testing => self.poll_test(now_us, out),
            EscPhase::Stopped if self.restartable() => self.probe(now_us, out),
            EscPhase::Stopped => self.retry_stop(now_us, out),
            EscPhase::Disabled => self.probe(now_us, out),
        }
    }

    /// A motor test: the start-up ramp on the tested ESC alone, then its speed re-sent, the
    /// stop at its end.
    fn poll_test(&mut self, now_us: i64, out: &mut Vec<(CycleKind, Cycle)>) {
        let Some((test, from_us, until_us)) = self.test else {
            return;
        };
        if now_us >= until_us {
            return self.stop(StopReason::MotorTestDone, now_us, out);
        }
        while let Some(&(at, action)) = self.ramp.get(self.ramp_next) {
            if self.ramp_start_us + at as i64 > now_us {
                break;
            }
            self.ramp_next += 1;
            if let EscAction::SpeedAll(v) = action {
                let mut writes = self.map.addresses.map(|a| (a, REG_SPEED, 0));
                writes[test.motor].2 = v;
                out.push((CycleKind::Ramp, writes));
            }
        }
        if now_us >= from_us && now_us >= self.next_resend_us {
            out.push((CycleKind::Speeds, self.speeds(&self.values)));
            self.next_resend_us += self.resend_us;
            if self.next_resend_us <= now_us {
                self.next_resend_us = now_us + self.resend_us;
            }
        }
    }

    /// Disabled ESCs (before the first flight, between flights) are probed every
    /// [`PROBE_PERIOD_US`]: the pre-arm check asks whether each one answers.
    fn probe(&mut self, now_us: i64, out: &mut Vec<(CycleKind, Cycle)>) {
        if now_us >= self.next_probe_us {
            self.next_probe_us = now_us + PROBE_PERIOD_US;
            let disable = self.map.addresses.map(|a| (a, REG_DISABLE, 0));
            out.push((CycleKind::Probe, disable));
        }
    }

    /// An unconfirmed stop: written again every re-send period until its retry time ran out.
    fn retry_stop(&mut self, now_us: i64, out: &mut Vec<(CycleKind, Cycle)>) {
        let Some(r) = &mut self.retry else {
            return;
        };
        if now_us >= r.deadline_us {
            return self.settle(now_us);
        }
        if now_us >= r.next_us {
            r.next_us = now_us + self.resend_us;
            self.push_stop(out);
        }
    }
}

/// One write cycle as executed, for the caller's bookkeeping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleDone {
    pub kind: CycleKind,
    /// Every write of the cycle was acknowledged.
    pub ok: bool,
    /// Which of the cycle's four writes (in motor order) were acknowledged.
    pub acked: [bool; 4],
    /// When the cycle's writes were done, µs since start.
    pub at_us: i64,
    /// After a failed cycle: the run of consecutive failed cycles, for the watchdog.
    pub failures: Option<Event>,
    /// This cycle settled a stop: nothing spins any more.
    pub stopped: bool,
}

impl CycleDone {
    /// What the watchdog hears of this cycle: the motors enabled, a run of failed cycles, the
    /// motors stopped.
    pub fn watchdog_events(&self) -> impl Iterator<Item = Event> + use<> {
        let enabled = (self.kind == CycleKind::Enable).then_some(Event::MotorsEnabled(self.at_us));
        let stopped = self.stopped.then_some(Event::MotorsStopped(self.at_us));
        enabled.into_iter().chain(self.failures).chain(stopped)
    }
}

/// The one ESC write loop of every mode: executes the driver's cycles through `write` (one
/// SMBus write; the bus is the caller's) and keeps the write counts and the run of failed
/// cycles the watchdog's missed-ack rule reads.
#[derive(Debug, Clone, Default)]
pub struct CycleRunner {
    pub writes: u64,
    pub failed_writes: u64,
    /// Consecutive failed cycles, and when the first of them was done.
    failed_cycles: u32,
    first_failure_us: i64,
}

impl CycleRunner {
    /// Executes and drains `cycles` (the `driver`'s) in order. `now_us` is read after each
    /// cycle's writes; the driver hears of each cycle's acknowledgements (a stop is confirmed
    /// by them); `done` hears of each cycle and, first, of the first failed write of a failing
    /// run (to be logged once, not per write).
    pub fn execute<E>(
        &mut self,
        driver: &mut EscDriver,
        cycles: &mut Vec<(CycleKind, Cycle)>,
        mut write: impl FnMut(u8, u8, u8) -> Result<(), E>,
        mut now_us: impl FnMut() -> i64,
        mut done: impl FnMut(CycleDone, Option<E>),
    ) {
        for (kind, cycle) in cycles.drain(..) {
            if matches!(kind, CycleKind::Enable | CycleKind::TestEnable) {
                // A flight's first cycle: an earlier flight's failed cycles do not count.
                self.failed_cycles = 0;
            }
            let mut ok = true;
            let mut acked = [true; 4];
            let mut first_error = None;
            for (m, (addr, reg, value)) in cycle.into_iter().enumerate() {
                self.writes += 1;
                if let Err(e) = write(addr, reg, value) {
                    self.failed_writes += 1;
                    acked[m] = false;
                    if ok && self.failed_cycles == 0 && kind != CycleKind::Probe {
                        first_error = Some(e);
                    }
                    ok = false;
                }
            }
            let at_us = now_us();
            // A probe of disabled ESCs is the pre-arm check's, not the watchdog's.
            let failures = if kind == CycleKind::Probe {
                None
            } else if ok {
                self.failed_cycles = 0;
                None
            } else {
                if self.failed_cycles == 0 {
                    self.first_failure_us = at_us;
                }
                self.failed_cycles += 1;
                Some(Event::EscFailures {
                    cycles: self.failed_cycles,
                    first_us: self.first_failure_us,
                })
            };
            let mut cycle_done = CycleDone {
                kind,
                ok,
                acked,
                at_us,
                failures,
                stopped: false,
            };
            let settled_before = driver.stop_outcome().is_some();
            driver.on_done(&cycle_done);
            cycle_done.stopped = !settled_before && driver.stop_outcome().is_some();
            done(cycle_done, first_error);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::watchdog::TripReason;

    const TIMING: EscTiming = EscTiming {
        resend_us: 2_000,
        command_timeout_us: 25_000,
        halt_retry_us: 100_000,
    };

    fn driver() -> EscDriver {
        EscDriver::new(MotorMap::UQUAD, TIMING)
    }

    #[test]
    fn the_probe_names_the_silent_escs_and_is_not_a_watchdog_failure() {
        let mut d = driver();
        let mut runner = CycleRunner::default();
        let mut cycles = Vec::new();
        d.poll(0, &mut cycles);
        assert_eq!(
            d.silent_addresses(),
            MotorMap::UQUAD.addresses,
            "silent until probed"
        );
        let mut events = Vec::new();
        runner.execute(
            &mut d,
            &mut cycles,
            |addr, _, _| {
                if addr == MotorMap::UQUAD.addresses[2] {
                    Err(())
                } else {
                    Ok(())
                }
            },
            || 0,
            |done, _| events.extend(done.watchdog_events()),
        );
        assert_eq!(d.silent_addresses(), [MotorMap::UQUAD.addresses[2]]);
        assert_eq!(d.silent_mask(), 0b0100);
        assert!(events.is_empty(), "{events:?}");
    }

    #[test]
    fn boots_disabled_then_ramps_idles_and_follows_commands() {
        let mut d = driver();
        let mut out = Vec::new();
        d.poll(1_000_000, &mut out);
        // Before the start request only the pre-arm probe: a disable to every ESC.
        let probe = MotorMap::UQUAD.addresses.map(|a| (a, REG_DISABLE, 0));
        assert_eq!(
            out,
            [(CycleKind::Probe, probe)],
            "only the probe before the start"
        );
        d.poll(1_000_000 + PROBE_PERIOD_US - 1, &mut out);
        assert_eq!(out.len(), 1, "one probe per period");
        out.clear();
        d.command(&[300.0; 4], 0, 0, &mut out);
        assert!(out.is_empty(), "no command before the ramp");
        d.start(0);
        let mut t = 0;
        while d.phase() == EscPhase::Ramping {
            d.poll(t, &mut out);
            t += 100;
        }
        assert_eq!(out[0].0, CycleKind::Enable);
        assert_eq!(out.iter().filter(|c| c.0 == CycleKind::Ramp).count(), 1580);
        let idle = MotorMap::UQUAD.speed_writes(&[I2C_IDLE; 4]);
        assert_eq!(out.last().unwrap(), &(CycleKind::Speeds, idle));
        out.clear();
        // Re-sent every 2 ms.
        for k in 1..=5 {
            d.poll(t + k * 1_000, &mut out);
        }
        assert_eq!(out.len(), 2);
        out.clear();
        d.command(&[300.0; 4], t + 5_000, t + 5_300, &mut out);
        assert_eq!(out[0].0, CycleKind::Command);
        assert_eq!(out[0].1[0].2, i2c_from_rad_s(300.0) + 15);
        // A host's stall of 100 ms is not the command's age: it still runs 24 ms after it.
        let mut stalled = d.clone();
        stalled.excuse_stall(t + 6_000, t + 106_000);
        stalled.poll(t + 5_000 + 124_000, &mut out);
        assert_eq!(stalled.phase(), EscPhase::Running);
        stalled.poll(t + 5_000 + 125_001, &mut out);
        assert_eq!(stalled.stop_reason(), Some(StopReason::StaleCommand));
        // Stale after 25 ms without a newer command: zero, then disable.
        out.clear();
        d.poll(t + 5_000 + 25_001, &mut out);
        assert_eq!(d.phase(), EscPhase::Stopped);
        assert_eq!(out[0].0, CycleKind::StopZero);
        assert!(out[0].1.iter().all(|w| w.2 == 0));
        assert_eq!(out[1].0, CycleKind::StopDisable);
        assert_eq!(d.stop_reason(), Some(StopReason::StaleCommand));
        out.clear();
        d.poll(t + 100_000, &mut out);
        d.command(&[300.0; 4], 0, t + 100_000, &mut out);
        assert!(
            out.iter()
                .all(|c| matches!(c.0, CycleKind::StopZero | CycleKind::StopDisable)),
            "stopped stays stopped: only the stop is written again (not acknowledged here)"
        );
    }

    /// Runs `d`'s cycles, every write acknowledged, at `t_us`.
    fn run_all(d: &mut EscDriver, cycles: &mut Vec<(CycleKind, Cycle)>, t_us: i64) {
        CycleRunner::default().execute(d, cycles, |_, _, _| Ok::<(), ()>(()), || t_us, |_, _| {});
    }

    /// A driver started at `t_us` and run until its ramp is done; returns the time then.
    fn ramp_up(d: &mut EscDriver, mut t_us: i64) -> i64 {
        let mut cycles = Vec::new();
        d.start(t_us);
        while d.phase() == EscPhase::Ramping {
            d.poll(t_us, &mut cycles);
            run_all(d, &mut cycles, t_us);
            t_us += 1_000;
        }
        t_us
    }

    /// A motor test at `t_us` on a fresh driver, its enable cycle executed.
    fn testing(motor: usize, t_us: i64) -> (EscDriver, MotorTest) {
        let mut d = driver();
        let mut cycles = Vec::new();
        let test = MotorTest::new(motor, 10.0, 1.0);
        assert!(d.test_motor(test, t_us, &mut cycles));
        let (a, m) = (MotorMap::UQUAD.addresses, motor);
        assert_eq!(cycles[0].0, CycleKind::TestEnable);
        for (k, w) in cycles[0].1.iter().enumerate() {
            let reg = if k == m { REG_ENABLE } else { REG_DISABLE };
            assert_eq!(*w, (a[k], reg, 0), "only the tested ESC is enabled");
        }
        run_all(&mut d, &mut cycles, t_us);
        (d, test)
    }

    #[test]
    fn a_motor_test_spins_one_motor_alone_for_its_time_then_stops_as_a_disarm_does() {
        let t0 = 1_000_000;
        let (mut d, test) = testing(2, t0);
        assert_eq!(test.value, I2C_IDLE + 17, "10 % of the range above idle");
        assert_eq!((d.phase(), d.starts()), (EscPhase::Testing, 0));
        let mut cycles = Vec::new();
        let wait_us = crate::core::motor::ESC_ENABLE_WAIT_US as i64;
        d.poll(t0 + wait_us - 1, &mut cycles);
        assert!(
            cycles.is_empty(),
            "nothing spins during the ESC's enable wait"
        );
        let from = t0 + esc_startup_ramp_us() as i64;
        let mut t = t0 + wait_us;
        let (mut ramp, mut speeds) = (0, 0);
        while d.phase() == EscPhase::Testing {
            assert!(d.next_wake_us().is_some_and(|w| w >= t - 1_000));
            d.poll(t, &mut cycles);
            for (kind, cycle) in &cycles {
                let values: Vec<u8> = cycle.iter().map(|w| w.2).collect();
                let others: Vec<u8> = [0, 1, 3].iter().map(|&k| values[k]).collect();
                match kind {
                    CycleKind::Ramp => ramp += 1,
                    CycleKind::Speeds => {
                        assert!(t >= from, "the test's speed after the ramp");
                        assert_eq!(values[2], test.value + 15, "m2, trimmed");
                        speeds += 1;
                    }
                    _ => continue,
                }
                assert_eq!(others, [0, 0, 0], "m2 alone");
            }
            run_all(&mut d, &mut cycles, t);
            t += 1_000;
        }
        assert_eq!(
            ramp,
            esc_startup_ramp().count() - 1,
            "the start-up ramp, on m2"
        );
        assert_eq!(speeds, 500, "re-sent every 2 ms for 1 s");
        assert_eq!(d.stop_reason(), Some(StopReason::MotorTestDone));
        assert!(d.restartable(), "a flight (or another test) may follow");
        assert_eq!(d.silent_mask(), 0, "the stop's acknowledgements answer");
        assert!(d.test_motor(test, t, &mut cycles), "another test");
        d.start(t + 1);
        assert_eq!(
            (d.phase(), d.starts(), d.motor_test()),
            (EscPhase::Ramping, 1, None),
            "an arm's start takes every motor over"
        );
        assert!(
            !d.test_motor(test, t + 2, &mut cycles),
            "no test while flying"
        );
    }

    #[test]
    fn a_halt_during_a_motor_test_stops_it_for_good_and_no_test_follows_a_final_stop() {
        let (mut d, test) = testing(0, 0);
        let mut cycles = Vec::new();
        d.stop(StopReason::Halt(TripReason::Kill), 500_000, &mut cycles);
        assert_eq!(cycles[0].0, CycleKind::StopZero);
        run_all(&mut d, &mut cycles, 500_000);
        assert!(!d.restartable());
        assert_eq!(d.motor_test(), None);
        assert!(!d.test_motor(test, 600_000, &mut cycles));
        assert!(cycles.is_empty());
        d.poll(2_000_000, &mut cycles);
        assert!(cycles.is_empty(), "nothing spins after a final stop");
    }

    #[test]
    fn a_disarm_stop_lets_the_next_flight_start_and_every_other_stop_is_final() {
        let mut d = driver();
        let mut cycles = Vec::new();
        let t = ramp_up(&mut d, 0);
        assert_eq!((d.phase(), d.starts()), (EscPhase::Running, 1));
        d.stop(StopReason::Disarmed, t, &mut cycles);
        d.start(t);
        assert_eq!(
            d.phase(),
            EscPhase::Stopped,
            "no start before the stop settled"
        );
        run_all(&mut d, &mut cycles, t);
        assert!(d.restartable() && d.stop_outcome().is_some_and(|o| o.confirmed()));
        assert_eq!(
            d.silent_mask(),
            0,
            "the stop's acknowledgements answer for them"
        );
        // Probed between flights, then started again: the same ramp, from idle.
        d.poll(t + PROBE_PERIOD_US - 1, &mut cycles);
        assert!(cycles.is_empty(), "the next probe a period after the stop");
        d.poll(t + PROBE_PERIOD_US, &mut cycles);
        assert_eq!(cycles.first().map(|c| c.0), Some(CycleKind::Probe));
        CycleRunner::default().execute(
            &mut d,
            &mut cycles,
            |a, _, _| {
                if a == MotorMap::UQUAD.addresses[1] {
                    Err(())
                } else {
                    Ok(())
                }
            },
            || t + PROBE_PERIOD_US,
            |_, _| {},
        );
        assert_eq!(
            d.silent_mask(),
            0b0010,
            "an ESC silent between flights is named"
        );
        let t = ramp_up(&mut d, t + PROBE_PERIOD_US + 1);
        assert_eq!((d.phase(), d.starts()), (EscPhase::Running, 2));
        assert_eq!((d.stop_reason(), d.stop_outcome()), (None, None));
        // A halt between flights: final, settled at once by the disarm's confirmed stop.
        let mut between = d.clone();
        between.stop(StopReason::Disarmed, t, &mut cycles);
        run_all(&mut between, &mut cycles, t);
        between.stop(StopReason::Halt(TripReason::Kill), t + 7, &mut cycles);
        assert!(cycles.is_empty(), "nothing to write: the motors are off");
        assert!(!between.restartable());
        assert_eq!(between.stop_outcome().map(|o| o.settled_us), Some(t + 7));
        assert_eq!(between.silent_mask(), 0b1111, "an arm is refused");
        between.start(t + 8);
        assert_eq!(between.phase(), EscPhase::Stopped);
        for reason in [
            StopReason::Halt(TripReason::Kill),
            StopReason::StaleCommand,
            StopReason::Shutdown,
        ] {
            let mut d = driver();
            let t = ramp_up(&mut d, t);
            d.stop(reason, t, &mut cycles);
            run_all(&mut d, &mut cycles, t);
            d.start(t + 1);
            assert_eq!(d.phase(), EscPhase::Stopped, "{reason} is final");
            assert!(!d.restartable());
        }
    }

    #[test]
    fn non_finite_command_stops() {
        let mut d = driver();
        let mut out = Vec::new();
        d.start(0);
        d.poll(10_000_000, &mut out);
        out.clear();
        d.command(
            &[300.0, f64::NAN, 300.0, 300.0],
            10_000_000,
            10_000_000,
            &mut out,
        );
        assert_eq!(d.phase(), EscPhase::Stopped);
        assert_eq!(out.len(), 2);
    }
    /// Two cycles (speeds, then a command) through `runner`, every even address refusing
    /// when `failing`; what each cycle reported.
    fn two_cycles(
        runner: &mut CycleRunner,
        failing: bool,
        at_us: i64,
    ) -> Vec<(CycleDone, Option<u8>)> {
        let cycle = MotorMap::UQUAD.speed_writes(&[60; 4]);
        let mut cycles = vec![(CycleKind::Speeds, cycle), (CycleKind::Command, cycle)];
        let mut seen = Vec::new();
        runner.execute(
            &mut driver(),
            &mut cycles,
            |addr, _, _| {
                if failing && addr % 2 == 0 {
                    Err(addr)
                } else {
                    Ok(())
                }
            },
            || at_us,
            |done, first_error| seen.push((done, first_error)),
        );
        assert!(cycles.is_empty(), "drained");
        seen
    }

    #[test]
    fn the_write_loop_counts_failed_cycles_and_reports_the_first_error_once() {
        let mut runner = CycleRunner::default();
        let seen = two_cycles(&mut runner, false, 1_000);
        assert!(
            seen.iter()
                .all(|(d, e)| d.ok && d.failures.is_none() && e.is_none())
        );
        let mut seen = two_cycles(&mut runner, true, 2_000);
        seen.extend(two_cycles(&mut runner, true, 4_000));
        let failures: Vec<_> = seen.iter().map(|(d, _)| d.failures).collect();
        let want: Vec<_> = (1..=4)
            .map(|n| {
                Some(Event::EscFailures {
                    cycles: n,
                    first_us: 2_000,
                })
            })
            .collect();
        assert_eq!(failures, want);
        let errors = seen.iter().filter(|(_, e)| e.is_some()).count();
        assert_eq!(errors, 1, "the first failed write of a failing run, once");
        assert_eq!((runner.writes, runner.failed_writes), (24, 8));
        let seen = two_cycles(&mut runner, false, 6_000);
        assert!(seen.iter().all(|(d, _)| d.ok && d.failures.is_none()));
    }

    /// A running driver stopped at `t0`, its writes refused by the addresses `refusing` says
    /// (at a time, µs); runs until the stop settles and returns its outcome and every write.
    fn stop_with(refusing: impl Fn(u8, i64) -> bool) -> (StopOutcome, Vec<(u8, u8, u8, i64)>) {
        let (mut d, mut runner, mut out) = (driver(), CycleRunner::default(), Vec::new());
        d.start(0);
        d.poll(10_000_000, &mut out);
        out.clear();
        let t0 = 10_000_000;
        d.stop(StopReason::Halt(TripReason::ImuTimeout), t0, &mut out);
        let mut writes = Vec::new();
        let mut t = t0;
        while d.stop_outcome().is_none() {
            runner.execute(
                &mut d,
                &mut out,
                |a, r, v| {
                    writes.push((a, r, v, t));
                    if refusing(a, t) { Err(()) } else { Ok(()) }
                },
                || t,
                |_, _| {},
            );
            t = d.next_wake_us().unwrap_or(t + 1).max(t + 1);
            d.poll(t, &mut out);
            assert!(t < t0 + 1_000_000, "the stop settles");
        }
        (d.stop_outcome().unwrap(), writes)
    }

    #[test]
    fn an_acknowledged_stop_is_confirmed_at_once() {
        let (o, writes) = stop_with(|_, _| false);
        assert!(o.confirmed());
        assert_eq!(o.unconfirmed, [None; 4]);
        assert_eq!(o.settled_us, 10_000_000);
        assert_eq!(writes.len(), 8, "zero, then disable, once each");
    }

    #[test]
    fn a_refused_stop_is_retried_until_acknowledged() {
        // 0x6a refuses for 30 ms: retried every 2 ms, confirmed by its first acks.
        let (o, writes) = stop_with(|a, t| a == 0x6a && t < 10_030_000);
        assert!(o.confirmed(), "{o:?}");
        assert_eq!(o.settled_us, 10_030_000);
        let last: Vec<_> = writes.iter().rev().take(8).collect();
        assert!(last[..4].iter().all(|w| w.1 == REG_DISABLE), "disable last");
        assert!(
            last[4..].iter().all(|w| w.1 == REG_SPEED && w.2 == 0),
            "zero before it"
        );
    }

    #[test]
    fn a_stop_refused_to_the_end_names_the_escs_within_the_retry_time() {
        let (o, writes) = stop_with(|a, _| a == 0x6a || a == 0x68);
        assert!(!o.confirmed());
        assert_eq!(o.unconfirmed_addresses(), vec![0x6a, 0x68]);
        assert_eq!(o.settled_us, 10_000_000 + TIMING.halt_retry_us);
        assert!(
            writes
                .iter()
                .all(|w| w.3 < 10_000_000 + TIMING.halt_retry_us)
        );
        assert_eq!(writes.len(), 8 * 50, "a round every 2 ms for 100 ms");
    }

    #[test]
    fn a_stop_needs_the_zero_acknowledged_before_the_disable() {
        // The zero is refused once, the disable acknowledged: not confirmed until a round
        // with both.
        let (mut d, mut runner, mut out) = (driver(), CycleRunner::default(), Vec::new());
        d.start(0);
        d.poll(10_000_000, &mut out);
        out.clear();
        d.stop(StopReason::Shutdown, 10_000_000, &mut out);
        runner.execute(
            &mut d,
            &mut out,
            |_, r, _| if r == REG_SPEED { Err(()) } else { Ok(()) },
            || 10_000_000,
            |_, _| {},
        );
        assert_eq!(d.stop_outcome(), None);
        d.poll(10_002_000, &mut out);
        runner.execute(
            &mut d,
            &mut out,
            |_, _, _| Ok::<(), ()>(()),
            || 10_002_000,
            |_, _| {},
        );
        assert!(d.stop_outcome().unwrap().confirmed());
    }

    #[test]
    fn enabling_the_escs_is_told_to_the_watchdog() {
        let (mut d, mut runner, mut out) = (driver(), CycleRunner::default(), Vec::new());
        d.start(0);
        d.poll(0, &mut out);
        let mut events = Vec::new();
        runner.execute(
            &mut d,
            &mut out,
            |_, _, _| Ok::<(), ()>(()),
            || 5,
            |done, _| events.extend(done.watchdog_events()),
        );
        assert_eq!(events, vec![Event::MotorsEnabled(5)]);
    }
}
