//! The ESC writer's decisions as a pure state machine: when to enable, the start-up ramp,
//! re-sending the last speeds, trims, and when to write zero and disable (spec 6.3, 6.4).
//! The thread in `tasks::esc_writer` and the simulator's lock-step loop both drive it; it
//! returns write cycles (four SMBus writes each, one per ESC) and never touches a bus or a clock.

use crate::core::motor::{
    EscAction, I2C_IDLE, MotorMap, REG_DISABLE, REG_ENABLE, REG_SPEED, esc_startup_ramp,
    i2c_from_rad_s,
};
use crate::core::watchdog::Event;

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
}

#[derive(Debug, Clone)]
pub struct EscDriver {
    map: MotorMap,
    resend_us: i64,
    command_timeout_us: i64,
    phase: EscPhase,
    ramp: Vec<(u64, EscAction)>,
    ramp_next: usize,
    ramp_start_us: i64,
    values: [u8; 4],
    next_resend_us: i64,
    /// Arrival of the frame of the newest flight command.
    command_frame_us: Option<i64>,
    stop_reason: Option<String>,
}

impl EscDriver {
    pub fn new(map: MotorMap, resend_us: i64, command_timeout_us: i64) -> Self {
        EscDriver {
            map,
            resend_us,
            command_timeout_us,
            phase: EscPhase::Disabled,
            ramp: esc_startup_ramp().collect(),
            ramp_next: 0,
            ramp_start_us: 0,
            values: [I2C_IDLE; 4],
            next_resend_us: 0,
            command_frame_us: None,
            stop_reason: None,
        }
    }

    pub fn phase(&self) -> EscPhase {
        self.phase
    }

    pub fn stop_reason(&self) -> Option<&str> {
        self.stop_reason.as_deref()
    }

    /// When [`EscDriver::poll`] next has something to do; `None` when only a request can.
    pub fn next_wake_us(&self) -> Option<i64> {
        match self.phase {
            EscPhase::Ramping => self
                .ramp
                .get(self.ramp_next)
                .map(|(at, _)| self.ramp_start_us + *at as i64),
            EscPhase::Running => Some(self.next_resend_us),
            EscPhase::Disabled | EscPhase::Stopped => None,
        }
    }

    /// Start request: enable and ramp, from `now_us`.
    pub fn start(&mut self, now_us: i64) {
        if self.phase == EscPhase::Disabled {
            self.phase = EscPhase::Ramping;
            self.ramp_start_us = now_us;
            self.ramp_next = 0;
        }
    }

    fn speeds(&self, values: &[u8; 4]) -> Cycle {
        self.map.speed_writes(values)
    }

    /// Zero, then disable every ESC; then nothing more.
    pub fn stop(&mut self, reason: &str, out: &mut Vec<(CycleKind, Cycle)>) {
        if self.phase == EscPhase::Stopped {
            return;
        }
        if self.phase == EscPhase::Disabled {
            // Never enabled: nothing spins, nothing to write.
            self.phase = EscPhase::Stopped;
            self.stop_reason = Some(reason.to_string());
            return;
        }
        out.push((CycleKind::StopZero, self.speeds(&[0; 4])));
        out.push((
            CycleKind::StopDisable,
            self.map.addresses.map(|a| (a, REG_DISABLE, 0)),
        ));
        self.phase = EscPhase::Stopped;
        self.stop_reason = Some(reason.to_string());
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
            return self.stop("non-finite motor command", out);
        }
        self.values = w_rad_s.map(i2c_from_rad_s);
        self.command_frame_us = Some(frame_us);
        out.push((CycleKind::Command, self.speeds(&self.values)));
        self.next_resend_us = now_us + self.resend_us;
    }

    /// Does what is due at `now_us`: ramp steps, the periodic re-send, the stale-command stop.
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
                    && now_us - f > self.command_timeout_us
                {
                    return self.stop("stale motor command", out);
                }
                if now_us >= self.next_resend_us {
                    out.push((CycleKind::Speeds, self.speeds(&self.values)));
                    self.next_resend_us += self.resend_us;
                    if self.next_resend_us <= now_us {
                        self.next_resend_us = now_us + self.resend_us;
                    }
                }
            }
            EscPhase::Disabled | EscPhase::Stopped => {}
        }
    }
}

/// One write cycle as executed, for the caller's bookkeeping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleDone {
    pub kind: CycleKind,
    /// Every write of the cycle was acknowledged.
    pub ok: bool,
    /// When the cycle's writes were done, µs since start.
    pub at_us: i64,
    /// After a failed cycle: the run of consecutive failed cycles, for the watchdog.
    pub failures: Option<Event>,
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
    /// Executes and drains `cycles` in order. `now_us` is read after each cycle's writes;
    /// `done` hears of each cycle and, first, of the first failed write of a failing run (to
    /// be logged once, not per write).
    pub fn execute<E>(
        &mut self,
        cycles: &mut Vec<(CycleKind, Cycle)>,
        mut write: impl FnMut(u8, u8, u8) -> Result<(), E>,
        mut now_us: impl FnMut() -> i64,
        mut done: impl FnMut(CycleDone, Option<E>),
    ) {
        for (kind, cycle) in cycles.drain(..) {
            let mut ok = true;
            let mut first_error = None;
            for (addr, reg, value) in cycle {
                self.writes += 1;
                if let Err(e) = write(addr, reg, value) {
                    self.failed_writes += 1;
                    if ok && self.failed_cycles == 0 {
                        first_error = Some(e);
                    }
                    ok = false;
                }
            }
            let at_us = now_us();
            let failures = if ok {
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
            let cycle_done = CycleDone {
                kind,
                ok,
                at_us,
                failures,
            };
            done(cycle_done, first_error);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn driver() -> EscDriver {
        EscDriver::new(MotorMap::UQUAD, 2_000, 25_000)
    }

    #[test]
    fn boots_disabled_then_ramps_idles_and_follows_commands() {
        let mut d = driver();
        let mut out = Vec::new();
        d.poll(1_000_000, &mut out);
        assert!(out.is_empty(), "nothing written before the start request");
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
        // Stale after 25 ms without a newer command: zero, then disable.
        out.clear();
        d.poll(t + 5_000 + 25_001, &mut out);
        assert_eq!(d.phase(), EscPhase::Stopped);
        assert_eq!(out[0].0, CycleKind::StopZero);
        assert!(out[0].1.iter().all(|w| w.2 == 0));
        assert_eq!(out[1].0, CycleKind::StopDisable);
        assert_eq!(d.stop_reason(), Some("stale motor command"));
        out.clear();
        d.poll(t + 100_000, &mut out);
        d.command(&[300.0; 4], 0, t + 100_000, &mut out);
        assert!(out.is_empty(), "stopped stays stopped");
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
}
