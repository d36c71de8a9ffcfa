//! The ESC bus: SMBus "write byte data" transactions (spec 6.3) behind a small trait, with the
//! Linux i2c-dev implementation and a recording mock for tests and the simulator.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// A failed bus transaction (the ESC did not acknowledge, or the device failed).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("I2C write to 0x{addr:02x} register 0x{reg:02x} failed: {reason}")]
pub struct BusError {
    pub addr: u8,
    pub reg: u8,
    pub reason: String,
}

/// The one operation the ESCs need. Implementations block (an ioctl): call them from a
/// dedicated thread, never from an async worker.
pub trait EscBus: Send {
    fn write_byte_data(&mut self, addr: u8, reg: u8, value: u8) -> Result<(), BusError>;
}

/// Linux i2c-dev: one device handle per ESC address on the bus (e.g. `/dev/i2c-2`).
pub struct LinuxEscBus {
    path: PathBuf,
    devices: HashMap<u8, i2cdev::linux::LinuxI2CDevice>,
}

impl LinuxEscBus {
    /// Opens `path` once per address; fails with the path and address named.
    pub fn open(path: &Path, addresses: &[u8]) -> anyhow::Result<Self> {
        use anyhow::Context;
        let mut devices = HashMap::new();
        for &a in addresses {
            let dev =
                i2cdev::linux::LinuxI2CDevice::new(path, u16::from(a)).with_context(|| {
                    format!(
                        "cannot open I2C bus {} for address 0x{a:02x}",
                        path.display()
                    )
                })?;
            devices.insert(a, dev);
        }
        Ok(LinuxEscBus {
            path: path.to_path_buf(),
            devices,
        })
    }
}

impl EscBus for LinuxEscBus {
    fn write_byte_data(&mut self, addr: u8, reg: u8, value: u8) -> Result<(), BusError> {
        use i2cdev::core::I2CDevice;
        let dev = self.devices.get_mut(&addr).ok_or_else(|| BusError {
            addr,
            reg,
            reason: format!("address not opened on {}", self.path.display()),
        })?;
        dev.smbus_write_byte_data(reg, value).map_err(|e| BusError {
            addr,
            reg,
            reason: e.to_string(),
        })
    }
}

/// One recorded transaction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Transaction {
    pub addr: u8,
    pub reg: u8,
    pub value: u8,
    /// When it was written.
    pub at: Instant,
    /// Whether the mock acknowledged it.
    pub acked: bool,
}

/// A bus that records every transaction; it can be told to fail (no acknowledgement).
#[derive(Clone, Default)]
pub struct MockBus {
    log: Arc<Mutex<Vec<Transaction>>>,
    failing: Arc<AtomicBool>,
}

impl MockBus {
    pub fn new() -> Self {
        Self::default()
    }

    /// Every transaction so far, in order.
    pub fn transactions(&self) -> Vec<Transaction> {
        self.log.lock().map(|l| l.clone()).unwrap_or_default()
    }

    /// From now on every write fails (true) or succeeds (false).
    pub fn set_failing(&self, failing: bool) {
        self.failing.store(failing, Ordering::SeqCst);
    }
}

impl EscBus for MockBus {
    fn write_byte_data(&mut self, addr: u8, reg: u8, value: u8) -> Result<(), BusError> {
        let acked = !self.failing.load(Ordering::SeqCst);
        if let Ok(mut l) = self.log.lock() {
            l.push(Transaction {
                addr,
                reg,
                value,
                at: Instant::now(),
                acked,
            });
        }
        if acked {
            Ok(())
        } else {
            Err(BusError {
                addr,
                reg,
                reason: "no acknowledgement (mock)".into(),
            })
        }
    }
}
