//! MAVLink FTP (FILE_TRANSFER_PROTOCOL): no file is served yet, and every request is answered
//! at once, so a ground station that asks for the parameter file by FTP first falls back to
//! PARAM_REQUEST_LIST at once instead of after a dozen unanswered tries. Opening, listing or
//! reading: NAK "file not found"; ending a session or all of them: ACK (there are none);
//! anything else: NAK "unknown command". The payload's layout is the FTP service's: sequence
//! number (u16), session, opcode, size, the request's opcode, burst complete, padding, offset
//! (u32), data.

use super::Connection;
use mavlink::dialects::common::*;

/// Opcodes (MAVLink FTP).
const TERMINATE_SESSION: u8 = 1;
const RESET_SESSIONS: u8 = 2;
const LIST_DIRECTORY: u8 = 3;
const OPEN_FILE_RO: u8 = 4;
const READ_FILE: u8 = 5;
const BURST_READ_FILE: u8 = 15;
const CALC_FILE_CRC32: u8 = 14;
const RSP_ACK: u8 = 128;
const RSP_NAK: u8 = 129;
/// Error codes of a NAK's first data byte.
const ERR_UNKNOWN_COMMAND: u8 = 7;
const ERR_FILE_NOT_FOUND: u8 = 10;

/// The answer to FTP request `req`: its payload.
pub fn answer(req: &[u8; 251]) -> [u8; 251] {
    let seq = u16::from_le_bytes([req[0], req[1]]).wrapping_add(1);
    let opcode = req[3];
    let mut out = [0u8; 251];
    out[0..2].copy_from_slice(&seq.to_le_bytes());
    out[2] = req[2];
    out[5] = opcode;
    match opcode {
        TERMINATE_SESSION | RESET_SESSIONS => out[3] = RSP_ACK,
        LIST_DIRECTORY | OPEN_FILE_RO | READ_FILE | BURST_READ_FILE | CALC_FILE_CRC32 => {
            out[3] = RSP_NAK;
            out[4] = 1;
            out[12] = ERR_FILE_NOT_FOUND;
        }
        _ => {
            out[3] = RSP_NAK;
            out[4] = 1;
            out[12] = ERR_UNKNOWN_COMMAND;
        }
    }
    out
}

impl Connection {
    /// A FILE_TRANSFER_PROTOCOL request for this vehicle: answered at once, to its sender.
    pub(super) fn on_ftp(&mut self, f: FILE_TRANSFER_PROTOCOL_DATA, from: (u8, u8)) {
        // A reply (ACK or NAK) is not a request: never answered, or two ends would loop.
        if f.payload[3] >= RSP_ACK {
            return;
        }
        let msg = MavMessage::FILE_TRANSFER_PROTOCOL(FILE_TRANSFER_PROTOCOL_DATA {
            target_network: 0,
            target_system: from.0,
            target_component: from.1,
            payload: answer(&f.payload),
        });
        self.send(&msg);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(seq: u16, session: u8, opcode: u8) -> [u8; 251] {
        let mut p = [0u8; 251];
        p[0..2].copy_from_slice(&seq.to_le_bytes());
        p[2] = session;
        p[3] = opcode;
        p
    }

    #[test]
    fn an_open_is_refused_as_not_found_and_a_reset_acknowledged() {
        let a = answer(&request(41, 0, OPEN_FILE_RO));
        assert_eq!(u16::from_le_bytes([a[0], a[1]]), 42);
        assert_eq!(
            (a[3], a[4], a[5], a[12]),
            (RSP_NAK, 1, OPEN_FILE_RO, ERR_FILE_NOT_FOUND)
        );
        let a = answer(&request(u16::MAX, 3, RESET_SESSIONS));
        assert_eq!(u16::from_le_bytes([a[0], a[1]]), 0);
        assert_eq!((a[2], a[3], a[5]), (3, RSP_ACK, RESET_SESSIONS));
        let a = answer(&request(7, 0, 99));
        assert_eq!((a[3], a[12]), (RSP_NAK, ERR_UNKNOWN_COMMAND));
    }
}
