//! The simulated ESCs: they take the I2C register writes (enable, disable, speed) through the
//! same bus trait as the real ones, turn speed bytes into rad/s (the inverse of the cubic fit,
//! spec 6.1), and stop their motor when writes stop, as the real ESCs do.
//!
//! The simulated motors are the ones the per-motor trims were tuned for: a motor spins at the
//! speed of its byte minus its trim, so trimmed commands give equal speeds.

use crate::core::motor::{MotorMap, REG_DISABLE, REG_ENABLE, REG_SPEED, rad_s_from_i2c};
use crate::hw::esc_bus::{BusError, EscBus};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// An ESC without I2C traffic for this long stops its motor, µs.
pub const ESC_SILENCE_TIMEOUT_US: i64 = 50_000;

/// Runs alone kept per ESC (a motor test each; more are counted, not kept).
pub const RUNS_ALONE_KEPT: usize = 16;

/// A motor driven alone: speed writes to this ESC while every other one was stopped
/// (disabled or at 0), as a motor test makes them. A flight's writes always go to all four.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RunAlone {
    /// The first write, s since the start.
    pub start_s: f64,
    /// From the first write to the last, s.
    pub seconds: f64,
    /// The last value written (its trim included): what it was held at.
    pub value: u8,
    pub writes: u64,
}

/// The run alone being written: its first and last write, µs, last value and writes.
#[derive(Debug, Clone, Copy)]
struct OpenRun {
    motor: usize,
    first_us: i64,
    last_us: i64,
    value: u8,
    writes: u64,
}

impl OpenRun {
    fn closed(&self) -> RunAlone {
        RunAlone {
            start_s: self.first_us as f64 / 1e6,
            seconds: (self.last_us - self.first_us) as f64 / 1e6,
            value: self.value,
            writes: self.writes,
        }
    }
}

#[derive(Debug, Clone)]
pub struct EscModel {
    map: MotorMap,
    enabled: [bool; 4],
    value: [u8; 4],
    last_write_us: [Option<i64>; 4],
    /// The last two acknowledged writes to each ESC (register, value), oldest first.
    last_writes: [[Option<(u8, u8)>; 2]; 4],
    /// Fault injection: every write goes unacknowledged and is not applied.
    pub failing: bool,
    /// Each ESC's runs alone (the first [`RUNS_ALONE_KEPT`]), and the one being written.
    runs_alone: [Vec<RunAlone>; 4],
    open_run: Option<OpenRun>,
}

impl EscModel {
    pub fn new(map: MotorMap) -> Self {
        EscModel {
            map,
            enabled: [false; 4],
            value: [0; 4],
            last_write_us: [None; 4],
            last_writes: [[None; 2]; 4],
            failing: false,
            runs_alone: Default::default(),
            open_run: None,
        }
    }

    /// One SMBus write at `now_us`.
    pub fn write(&mut self, addr: u8, reg: u8, value: u8, now_us: i64) -> Result<(), BusError> {
        let err = |reason: &str| BusError {
            addr,
            reg,
            reason: reason.to_string(),
        };
        let Some(m) = self.map.addresses.iter().position(|&a| a == addr) else {
            return Err(err("no ESC at this address"));
        };
        if self.failing {
            return Err(err("no acknowledgement (simulated fault)"));
        }
        self.last_write_us[m] = Some(now_us);
        self.last_writes[m] = [self.last_writes[m][1], Some((reg, value))];
        match reg {
            REG_ENABLE => self.enabled[m] = true,
            REG_DISABLE => {
                self.enabled[m] = false;
                self.value[m] = 0;
            }
            REG_SPEED => self.value[m] = value,
            _ => return Err(err("unknown register")),
        }
        self.note_run_alone(m, reg, value, now_us);
        Ok(())
    }

    /// Follows motors driven alone: while exactly one ESC spins (enabled, above 0), a speed
    /// write to it extends its run (writes to the others keep it going); otherwise the run
    /// ends. One write alone is not a run (a start-up ramp's first write of a cycle comes
    /// before the others').
    fn note_run_alone(&mut self, m: usize, reg: u8, value: u8, now_us: i64) {
        let mut spinning = (0..4).filter(|&k| self.enabled[k] && self.value[k] > 0);
        let alone = match (spinning.next(), spinning.next()) {
            (Some(k), None) => Some(k),
            _ => None,
        };
        let written = reg == REG_SPEED && alone == Some(m);
        match (alone, &mut self.open_run) {
            (Some(k), Some(r)) if r.motor == k => {
                if written {
                    r.last_us = now_us;
                    r.value = value;
                    r.writes += 1;
                }
            }
            _ => {
                self.close_run_alone();
                if written {
                    self.open_run = Some(OpenRun {
                        motor: m,
                        first_us: now_us,
                        last_us: now_us,
                        value,
                        writes: 1,
                    });
                }
            }
        }
    }

    fn close_run_alone(&mut self) {
        let Some(r) = self.open_run.take() else {
            return;
        };
        if r.writes < 2 {
            return;
        }
        let runs = &mut self.runs_alone[r.motor];
        if runs.len() < RUNS_ALONE_KEPT {
            runs.push(r.closed());
        }
    }

    /// The speed each motor is driven to at `now_us`, rad/s.
    pub fn commands_rad_s(&self, now_us: i64) -> [f64; 4] {
        std::array::from_fn(|m| {
            let alive = self.last_write_us[m].is_some_and(|t| now_us - t <= ESC_SILENCE_TIMEOUT_US);
            if !(self.enabled[m] && alive) || self.value[m] == 0 {
                return 0.0;
            }
            let untrimmed = (i16::from(self.value[m]) - self.map.trims[m]).clamp(0, 255) as u8;
            rad_s_from_i2c(untrimmed)
        })
    }
}

/// What an ESC was left with at the end of a run, for the sim report.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct EscEnd {
    /// Its I2C address, as "0x69".
    pub address: String,
    pub enabled: bool,
    /// Its last two acknowledged writes, oldest first, as "speed 0", "disable"...
    pub last_writes: Vec<String>,
    /// Its motor's runs alone (motor tests), if any: the first [`RUNS_ALONE_KEPT`].
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub runs_alone: Vec<RunAlone>,
}

impl EscModel {
    /// Each ESC's state and last writes, in motor order.
    pub fn end_state(&self) -> Vec<EscEnd> {
        let mut runs = self.runs_alone.clone();
        if let Some(r) = self.open_run.filter(|r| r.writes >= 2)
            && runs[r.motor].len() < RUNS_ALONE_KEPT
        {
            runs[r.motor].push(r.closed());
        }
        let name = |(reg, value): (u8, u8)| match reg {
            REG_ENABLE => "enable".to_string(),
            REG_DISABLE => "disable".to_string(),
            REG_SPEED => format!("speed {value}"),
            _ => format!("register {reg} {value}"),
        };
        (0..4)
            .map(|m| EscEnd {
                address: format!("0x{:02x}", self.map.addresses[m]),
                enabled: self.enabled[m],
                last_writes: self.last_writes[m]
                    .iter()
                    .flatten()
                    .map(|&w| name(w))
                    .collect(),
                runs_alone: std::mem::take(&mut runs[m]),
            })
            .collect()
    }
}

/// The model behind the bus trait, on the wall clock (`--realtime`).
#[derive(Clone)]
pub struct SimBus {
    pub model: Arc<Mutex<EscModel>>,
    pub start: Instant,
}

impl EscBus for SimBus {
    fn write_byte_data(&mut self, addr: u8, reg: u8, value: u8) -> Result<(), BusError> {
        let now_us = self.start.elapsed().as_micros() as i64;
        match self.model.lock() {
            Ok(mut m) => m.write(addr, reg, value, now_us),
            Err(_) => Err(BusError {
                addr,
                reg,
                reason: "simulated ESC state poisoned".into(),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::motor::i2c_from_rad_s;

    #[test]
    fn trimmed_bytes_drive_equal_speeds_and_silence_stops() {
        let map = MotorMap::UQUAD;
        let mut esc = EscModel::new(map);
        let v = i2c_from_rad_s(300.0);
        for (addr, reg, val) in map.addresses.map(|a| (a, REG_ENABLE, 0)) {
            esc.write(addr, reg, val, 0).unwrap();
        }
        for (addr, reg, val) in map.speed_writes(&[v; 4]) {
            esc.write(addr, reg, val, 1_000).unwrap();
        }
        let w = esc.commands_rad_s(2_000);
        assert!(w.iter().all(|x| (x - w[0]).abs() < 1e-9), "{w:?}");
        assert!((w[0] - 300.0).abs() < 2.0, "{w:?}");
        assert_eq!(
            esc.commands_rad_s(1_000 + ESC_SILENCE_TIMEOUT_US + 1),
            [0.0; 4]
        );
        esc.failing = true;
        assert!(esc.write(0x69, REG_SPEED, 10, 5).is_err());
        assert!(esc.write(0x10, REG_SPEED, 10, 5).is_err());
    }

    #[test]
    fn a_motor_driven_alone_is_a_run_and_a_start_up_ramp_is_not() {
        let map = MotorMap::UQUAD;
        let mut esc = EscModel::new(map);
        let mut t = 0;
        let write = |esc: &mut EscModel, cycle: [(u8, u8, u8); 4], t: &mut i64| {
            for (addr, reg, val) in cycle {
                esc.write(addr, reg, val, *t).unwrap();
            }
            *t += 2_000;
        };
        // A flight: every ESC enabled, ramped together, stopped together.
        write(&mut esc, map.addresses.map(|a| (a, REG_ENABLE, 0)), &mut t);
        for v in [5, 55, 60] {
            write(&mut esc, map.addresses.map(|a| (a, REG_SPEED, v)), &mut t);
        }
        write(&mut esc, map.speed_writes(&[0; 4]), &mut t);
        write(&mut esc, map.addresses.map(|a| (a, REG_DISABLE, 0)), &mut t);
        assert!(esc.end_state().iter().all(|e| e.runs_alone.is_empty()));
        // A motor test of m2: its ESC alone enabled and driven 100 times, then stopped.
        let mut enable = map.addresses.map(|a| (a, REG_DISABLE, 0));
        enable[2].1 = REG_ENABLE;
        write(&mut esc, enable, &mut t);
        let from = t;
        for _ in 0..100 {
            write(&mut esc, map.speed_writes(&[0, 0, 67, 0]), &mut t);
        }
        write(&mut esc, map.speed_writes(&[0; 4]), &mut t);
        let end = esc.end_state();
        let runs: Vec<usize> = end.iter().map(|e| e.runs_alone.len()).collect();
        assert_eq!(runs, [0, 0, 1, 0]);
        let run = end[2].runs_alone[0];
        assert_eq!((run.value, run.writes), (67 + 15, 100));
        assert!((run.start_s - from as f64 / 1e6).abs() < 1e-9);
        assert!((run.seconds - 0.198).abs() < 1e-9, "{run:?}");
    }
}
