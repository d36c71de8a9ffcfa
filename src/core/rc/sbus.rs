//! SBUS (spec: none, the original had no radio receiver; Futaba's protocol, spoken by FrSky
//! and most receivers): 100 000 baud, 8 data bits, even parity, 2 stop
//! bits, the signal inverted; a 25-byte frame every 7 ms (high speed) or 14 ms: the header
//! 0x0F, 16 channels of 11 bits packed least significant bit first (22 bytes), a flags byte
//! (bit 0 channel 17, bit 1 channel 18, bit 2 frame lost, bit 3 failsafe; the others unused)
//! and an end byte (0x00; SBUS2 receivers send 0x04, 0x14, 0x24 or 0x34). A candidate whose
//! end byte is wrong is not a frame: the search goes on from the byte after its start.

use super::{DecoderStats, RcEvent, RcFrame, pack_channels, unpack_channels};

pub const FRAME_LEN: usize = 25;
pub const HEADER: u8 = 0x0f;
const FLAG_FRAME_LOST: u8 = 1 << 2;
const FLAG_FAILSAFE: u8 = 1 << 3;

/// The end bytes a frame may have: SBUS's, and SBUS2's four telemetry-slot markers.
fn is_end(b: u8) -> bool {
    matches!(b, 0x00 | 0x04 | 0x14 | 0x24 | 0x34)
}

/// The frame in `b`, if it is one.
pub fn parse(b: &[u8; FRAME_LEN]) -> Option<RcFrame> {
    let flags = b[23];
    if b[0] != HEADER || !is_end(b[24]) {
        return None;
    }
    let mut packed = [0u8; 22];
    packed.copy_from_slice(&b[1..23]);
    Some(RcFrame {
        channels: unpack_channels(&packed),
        frame_lost: flags & FLAG_FRAME_LOST != 0,
        failsafe: flags & FLAG_FAILSAFE != 0,
    })
}

/// A frame's 25 bytes (channels 17 and 18 off, end byte 0x00).
pub fn encode(f: &RcFrame) -> [u8; FRAME_LEN] {
    let mut b = [0u8; FRAME_LEN];
    b[0] = HEADER;
    b[1..23].copy_from_slice(&pack_channels(&f.channels));
    b[23] =
        if f.frame_lost { FLAG_FRAME_LOST } else { 0 } | if f.failsafe { FLAG_FAILSAFE } else { 0 };
    b
}

/// SBUS bytes in, frames out, whatever the bytes' split.
#[derive(Debug, Clone, Default)]
pub struct SbusDecoder {
    buf: Vec<u8>,
    stats: DecoderStats,
}

impl SbusDecoder {
    pub fn new() -> Self {
        SbusDecoder {
            buf: Vec::with_capacity(2 * FRAME_LEN),
            stats: DecoderStats::default(),
        }
    }

    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Bytes held for a frame not yet complete.
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }

    /// Takes `bytes`, appending each frame completed to `out`. At most a frame's worth less
    /// one byte stays buffered, starting with a header byte.
    pub fn feed(&mut self, bytes: &[u8], out: &mut Vec<RcEvent>) {
        for &b in bytes {
            if self.buf.is_empty() && b != HEADER {
                self.stats.discarded_bytes += 1;
                continue;
            }
            self.buf.push(b);
            if self.buf.len() == FRAME_LEN {
                self.take(out);
            }
        }
    }

    /// A full candidate: a frame, or its first byte dropped and the rest searched again.
    fn take(&mut self, out: &mut Vec<RcEvent>) {
        let mut candidate = [0u8; FRAME_LEN];
        candidate.copy_from_slice(&self.buf);
        if let Some(f) = parse(&candidate) {
            self.stats.frames += 1;
            out.push(RcEvent::Channels(f));
            self.buf.clear();
            return;
        }
        self.stats.rejected_frames += 1;
        self.stats.discarded_bytes += 1;
        let rest: Vec<u8> = self.buf.drain(..).skip(1).collect();
        let at = rest.iter().position(|&b| b == HEADER).unwrap_or(rest.len());
        self.stats.discarded_bytes += at as u64;
        // Fewer than a frame's bytes: no second candidate completes here.
        self.buf.extend_from_slice(&rest[at..]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        s.split(':')
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    /// Frames and the channels, channel 17 and 18 and flags decoded from them by an
    /// independent implementation: zendes/SBUS's parser (SBUS.cpp at 5cf196c), as published
    /// with a Python SBUS parser's unit tests (random frames covering every combination of
    /// the digital channels and the two flags).
    const INDEPENDENT: [(&str, &str, bool, bool); 4] = [
        (
            "0F:1A:28:A2:95:7C:07:EA:05:F6:CE:BF:61:AD:79:3F:2D:B7:CA:FA:62:87:0D:85:00",
            "01A:445:256:3BE:6A0:40B:3BD:5FE:561:735:4FD:396:4AB:5F5:1D8:06C",
            true,
            false,
        ),
        (
            "0F:7A:F6:E1:E7:0B:54:07:78:4F:39:75:19:05:40:27:91:28:2E:B5:CC:A7:61:6B:00",
            "67A:43E:79F:205:075:6F0:653:3A9:519:000:49D:448:2E2:16A:1F3:30D",
            false,
            true,
        ),
        (
            "0F:A3:9A:E1:15:24:C1:56:CC:C6:A5:9B:29:8D:B2:B4:5D:3B:77:48:B0:CC:82:6E:00",
            "2A3:433:057:092:56C:598:171:4DD:529:651:6D2:5AE:773:090:32C:416",
            true,
            true,
        ),
        (
            "0F:F0:F1:72:56:36:7C:02:A7:2A:D1:0B:DE:94:9B:59:86:E1:BD:EE:E7:9A:E1:A0:00",
            "1F0:65E:159:61B:027:54E:44A:05E:4DE:372:166:0C3:3DE:7DD:6B9:70C",
            false,
            false,
        ),
    ];

    #[test]
    fn frames_decode_as_an_independent_implementation_decodes_them() {
        for (frame, channels, lost, failsafe) in INDEPENDENT {
            let bytes: [u8; FRAME_LEN] = hex(frame).try_into().unwrap();
            let want: Vec<u16> = channels
                .split(':')
                .map(|c| u16::from_str_radix(c, 16).unwrap())
                .collect();
            let f = parse(&bytes).expect(frame);
            assert_eq!(f.channels.to_vec(), want, "{frame}");
            assert_eq!((f.frame_lost, f.failsafe), (lost, failsafe), "{frame}");
            // Re-encoded, the same but for the flags uquad does not read (channels 17, 18).
            let mut re = encode(&f);
            re[23] |= bytes[23] & !0b1100;
            assert_eq!(re, bytes, "re-encoded");
        }
    }

    #[test]
    fn the_decoder_finds_frames_after_noise_and_across_any_split() {
        let f = RcFrame {
            channels: std::array::from_fn(|k| 172 + 100 * k as u16),
            frame_lost: false,
            failsafe: false,
        };
        let mut stream = vec![0x0f, 0x33, 0x0f, 0xff];
        stream.extend(encode(&f));
        stream.extend(&encode(&f)[..10]);
        stream.extend(encode(&RcFrame {
            failsafe: true,
            ..f
        }));
        for split in [1, 7, 25, stream.len()] {
            let mut d = SbusDecoder::new();
            let mut out = Vec::new();
            for chunk in stream.chunks(split) {
                d.feed(chunk, &mut out);
            }
            let failsafes: Vec<bool> = out
                .iter()
                .map(|e| matches!(e, RcEvent::Channels(f) if f.failsafe))
                .collect();
            assert_eq!(failsafes, [false, true], "split {split}: {out:?}");
            assert_eq!(d.stats().frames, 2);
        }
    }
}
