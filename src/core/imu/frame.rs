//! IMU frames: the 30-byte binary flight frame and the ASCII debug frame.
//!
//! Spec sections 1.2 (binary layout), 1.3 (ASCII frame) and 1.4 (host synchronisation).
//! The decoder is a pure byte-stream state machine; it never reads a clock. Differences from
//! the original's host code, chosen on purpose:
//! - a frame whose end byte is not `'Z'` drops only its start byte and the scan resumes at the
//!   next byte (the original dropped the whole candidate), so a false sync on a data byte that
//!   looks like a start byte costs no real frame;
//! - `T_us` is kept as the full `u32` (the original truncated it to 16 bits; logs still print it
//!   whole, which equals the original for the nominal 10 000 µs);
//! - the temperature is decoded as the signed `i16` the firmware sends (the original read it as
//!   `u16`, which breaks below 0 °C).

use bytes::{Buf, BytesMut};

/// Length of a binary frame in bytes (spec 1.2).
pub const FRAME_LEN: usize = 30;
/// The end byte of every frame.
pub const END_BYTE: u8 = b'Z';

/// `true` for the two start bytes the firmware alternates between ('A' and 'C').
pub fn is_start_byte(b: u8) -> bool {
    b == b'A' || b == b'C'
}

/// One raw IMU sample, as counts straight from the sensors.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RawFrame {
    /// Microseconds since the previous frame was sent (firmware clock).
    pub t_us: u32,
    /// ADXL345 counts, x y z.
    pub acc: [i16; 3],
    /// ITG-3200 counts, x y z.
    pub gyro: [i16; 3],
    /// HMC5843 counts, x y z.
    pub magn: [i16; 3],
    /// BMP085 temperature in 0.1 °C.
    pub temp_dc: i16,
    /// BMP085 pressure in Pa.
    pub pres_pa: u32,
}

impl RawFrame {
    /// Serialises the frame into the 30-byte binary layout with the given start byte.
    pub fn encode(&self, start: u8) -> [u8; FRAME_LEN] {
        let mut out = [0u8; FRAME_LEN];
        out[0] = start;
        out[1..5].copy_from_slice(&self.t_us.to_le_bytes());
        let fields = self.acc.iter().chain(&self.gyro).chain(&self.magn);
        for (i, v) in fields.enumerate() {
            let at = 5 + 2 * i;
            out[at..at + 2].copy_from_slice(&v.to_le_bytes());
        }
        out[23..25].copy_from_slice(&self.temp_dc.to_le_bytes());
        out[25..29].copy_from_slice(&self.pres_pa.to_le_bytes());
        out[29] = END_BYTE;
        out
    }

    /// Parses a 30-byte candidate; `None` when the start or end byte is wrong.
    pub fn parse(bytes: &[u8; FRAME_LEN]) -> Option<RawFrame> {
        if !is_start_byte(bytes[0]) || bytes[29] != END_BYTE {
            return None;
        }
        let i16_at = |at: usize| i16::from_le_bytes([bytes[at], bytes[at + 1]]);
        let triple = |at: usize| [i16_at(at), i16_at(at + 2), i16_at(at + 4)];
        Some(RawFrame {
            t_us: u32::from_le_bytes([bytes[1], bytes[2], bytes[3], bytes[4]]),
            acc: triple(5),
            gyro: triple(11),
            magn: triple(17),
            temp_dc: i16_at(23),
            pres_pa: u32::from_le_bytes([bytes[25], bytes[26], bytes[27], bytes[28]]),
        })
    }

    /// Formats the frame as the firmware's ASCII debug line (spec 1.3), CR LF included.
    pub fn to_ascii(&self) -> String {
        format!(
            "A\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\tZ\r\n",
            self.t_us,
            self.acc[0],
            self.acc[1],
            self.acc[2],
            self.gyro[0],
            self.gyro[1],
            self.gyro[2],
            self.magn[0],
            self.magn[1],
            self.magn[2],
            self.temp_dc,
            self.pres_pa
        )
    }

    /// Parses one ASCII debug line (spec 1.3): `A`, 12 tab-separated integers, `Z`.
    pub fn from_ascii(line: &str) -> Result<RawFrame, AsciiFrameError> {
        let fields: Vec<&str> = line.trim_end_matches(['\r', '\n']).split('\t').collect();
        if fields.len() != 14 {
            return Err(AsciiFrameError::FieldCount(fields.len()));
        }
        if fields[0] != "A" || fields[13] != "Z" {
            return Err(AsciiFrameError::Markers);
        }
        fn num<T: std::str::FromStr>(s: &str, index: usize) -> Result<T, AsciiFrameError> {
            s.trim().parse().map_err(|_| AsciiFrameError::Number {
                index,
                text: s.to_string(),
            })
        }
        let n = |i: usize| num::<i16>(fields[i], i);
        Ok(RawFrame {
            t_us: num(fields[1], 1)?,
            acc: [n(2)?, n(3)?, n(4)?],
            gyro: [n(5)?, n(6)?, n(7)?],
            magn: [n(8)?, n(9)?, n(10)?],
            temp_dc: n(11)?,
            pres_pa: num(fields[12], 12)?,
        })
    }
}

/// Why an ASCII frame line was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum AsciiFrameError {
    #[error("expected 14 tab-separated fields, found {0}")]
    FieldCount(usize),
    #[error("the line must start with 'A' and end with 'Z'")]
    Markers,
    #[error("field {index} is not a valid integer: {text:?}")]
    Number { index: usize, text: String },
}

/// Counters of what the decoder threw away; they only grow.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DecoderStats {
    /// Frames accepted.
    pub frames: u64,
    /// Bytes skipped while looking for a start byte or after a rejected candidate.
    pub discarded_bytes: u64,
    /// Candidates that began with a start byte but did not end with `'Z'`.
    pub rejected_frames: u64,
}

/// Resynchronising decoder of the binary frame stream.
///
/// Produces the same frames however the input is split, because every decision depends only on
/// the bytes themselves: a candidate is judged once all 30 of its bytes are buffered.
#[derive(Debug, Default, Clone)]
pub struct FrameDecoder {
    stats: DecoderStats,
}

impl FrameDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Decodes the next frame from `buf`, consuming what it has judged. `None` = need more bytes.
    pub fn next_frame(&mut self, buf: &mut BytesMut) -> Option<RawFrame> {
        loop {
            // Skip to the first possible start byte.
            let skip = buf
                .iter()
                .position(|&b| is_start_byte(b))
                .unwrap_or(buf.len());
            if skip > 0 {
                self.stats.discarded_bytes += skip as u64;
                buf.advance(skip);
            }
            if buf.len() < FRAME_LEN {
                return None;
            }
            let mut candidate = [0u8; FRAME_LEN];
            candidate.copy_from_slice(&buf[..FRAME_LEN]);
            if let Some(frame) = RawFrame::parse(&candidate) {
                buf.advance(FRAME_LEN);
                self.stats.frames += 1;
                return Some(frame);
            }
            // False sync: drop the start byte only; a real frame may begin inside the candidate.
            self.stats.rejected_frames += 1;
            self.stats.discarded_bytes += 1;
            buf.advance(1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> RawFrame {
        RawFrame {
            t_us: 9996,
            acc: [0, 7, 193],
            gyro: [-54, 17, -22],
            magn: [-141, -268, 119],
            temp_dc: 386,
            pres_pa: 101_443,
        }
    }

    #[test]
    fn encode_parse_round_trip() {
        let f = sample();
        let bytes = f.encode(b'C');
        assert_eq!(bytes.len(), 30);
        assert_eq!(bytes[0], b'C');
        assert_eq!(bytes[29], b'Z');
        assert_eq!(&bytes[1..5], &9996u32.to_le_bytes());
        assert_eq!(RawFrame::parse(&bytes), Some(f));
    }

    #[test]
    fn garbage_then_frame() {
        let mut d = FrameDecoder::new();
        let mut buf = BytesMut::new();
        buf.extend_from_slice(b"xyzA\x00\x01");
        buf.extend_from_slice(&sample().encode(b'A'));
        assert_eq!(d.next_frame(&mut buf), Some(sample()));
        let s = d.stats();
        assert_eq!(s.frames, 1);
        assert_eq!(s.rejected_frames, 1);
        assert_eq!(s.discarded_bytes, 6);
        assert!(buf.is_empty());
    }

    #[test]
    fn ascii_round_trip_and_errors() {
        let f = sample();
        let line = f.to_ascii();
        assert!(line.ends_with("\tZ\r\n"));
        assert_eq!(RawFrame::from_ascii(&line), Ok(f));
        assert_eq!(
            RawFrame::from_ascii("A\t1\tZ"),
            Err(AsciiFrameError::FieldCount(3))
        );
        let bad = line.replace("193", "19x");
        assert!(matches!(
            RawFrame::from_ascii(&bad),
            Err(AsciiFrameError::Number { index: 4, .. })
        ));
    }
}
