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

/// `I2C_RETRIES` and `I2C_TIMEOUT` of linux/i2c-dev.h: the adapter's retries after a lost
/// arbitration, and its transfer timeout in units of 10 ms.
const I2C_RETRIES: libc::Ioctl = 0x0701;
const I2C_TIMEOUT: libc::Ioctl = 0x0702;
/// The longest an ESC write may block the writer thread, in the adapter's 10 ms units: one
/// unit, a tenth of the watchdog's tolerance for missed acks. The adapter's default (often
/// a second) would stall the ESC writer, and with it every motor, behind one stuck transfer.
const I2C_TIMEOUT_10MS: libc::c_ulong = 1;

/// Linux i2c-dev: one device handle per ESC address on the bus (e.g. `/dev/i2c-2`). Each
/// transfer fails after 10 ms at most and is not retried by the adapter: the ESC writer
/// counts the failure and retries itself.
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
            bound_transfers(&dev)
                .with_context(|| format!("cannot set the I2C timeout on {}", path.display()))?;
            devices.insert(a, dev);
        }
        Ok(LinuxEscBus {
            path: path.to_path_buf(),
            devices,
        })
    }
}

/// Sets the adapter's transfer timeout and retries (they apply to the whole adapter).
fn bound_transfers(dev: &i2cdev::linux::LinuxI2CDevice) -> std::io::Result<()> {
    use std::os::fd::AsRawFd;
    let fd = dev.as_raw_fd();
    for (request, value) in [
        (I2C_TIMEOUT, I2C_TIMEOUT_10MS),
        (I2C_RETRIES, 0 as libc::c_ulong),
    ] {
        // SAFETY: an i2c-dev ioctl taking an integer argument on a descriptor we own.
        if unsafe { libc::ioctl(fd, request, value) } < 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(())
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
