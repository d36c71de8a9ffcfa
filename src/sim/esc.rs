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
        Ok(())
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
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct EscEnd {
    /// Its I2C address, as "0x69".
    pub address: String,
    pub enabled: bool,
    /// Its last two acknowledged writes, oldest first, as "speed 0", "disable"...
    pub last_writes: Vec<String>,
}

impl EscModel {
    /// Each ESC's state and last writes, in motor order.
    pub fn end_state(&self) -> Vec<EscEnd> {
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
}
