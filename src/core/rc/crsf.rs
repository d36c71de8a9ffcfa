//! CRSF (spec: none, the original had no radio receiver; TBS Crossfire's protocol, spoken by
//! ExpressLRS too): 420 000 baud, 8N1, not inverted. A frame is an address
//! byte, a length (the bytes after it: type, payload and CRC; 2 to 62), a type, its payload
//! and a CRC-8 (polynomial 0xD5, DVB-S2) over the type and the payload. Read here:
//! RC_CHANNELS_PACKED (type 0x16: 16 channels of 11 bits, least significant bit first, 22
//! bytes) and LINK_STATISTICS (type 0x14: the uplink's RSSI per antenna, its link quality and
//! SNR, 10 bytes); other types are counted and skipped. A candidate whose length or CRC is
//! wrong is not a frame: the search goes on from the byte after its start.

use super::{DecoderStats, LinkStats, RcEvent, RcFrame, pack_channels, unpack_channels};

/// The longest frame, bytes (address and length included).
pub const FRAME_MAX: usize = 64;
pub const ADDRESS_FLIGHT_CONTROLLER: u8 = 0xc8;
pub const TYPE_LINK_STATISTICS: u8 = 0x14;
pub const TYPE_RC_CHANNELS_PACKED: u8 = 0x16;
/// RC_CHANNELS_PACKED's and LINK_STATISTICS's payloads, bytes.
const RC_PAYLOAD: usize = 22;
const LINK_PAYLOAD: usize = 10;

/// The addresses a frame may start with: the flight controller (what a receiver sends to
/// it), broadcast, the receiver, the transmitter module and the radio.
fn is_address(b: u8) -> bool {
    matches!(b, ADDRESS_FLIGHT_CONTROLLER | 0x00 | 0xec | 0xee | 0xea)
}

/// CRC-8 with polynomial 0xD5 (DVB-S2), from 0.
pub fn crc8(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |mut crc, &b| {
        crc ^= b;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 {
                (crc << 1) ^ 0xd5
            } else {
                crc << 1
            };
        }
        crc
    })
}

/// A frame to the flight controller: address, length, `kind`, `payload`, CRC.
fn frame(kind: u8, payload: &[u8]) -> Vec<u8> {
    let mut b = vec![ADDRESS_FLIGHT_CONTROLLER, payload.len() as u8 + 2, kind];
    b.extend_from_slice(payload);
    b.push(crc8(&b[2..]));
    b
}

/// RC_CHANNELS_PACKED of `channels` (26 bytes).
pub fn encode_channels(channels: &[u16; 16]) -> Vec<u8> {
    frame(TYPE_RC_CHANNELS_PACKED, &pack_channels(channels))
}

/// LINK_STATISTICS with `s` as the uplink of antenna 1 (14 bytes).
pub fn encode_link(s: &LinkStats) -> Vec<u8> {
    let rssi = s.rssi_dbm.clamp(-255, 0).unsigned_abs() as u8;
    let payload = [
        rssi,
        rssi,
        s.link_quality_pct,
        s.snr_db as u8,
        0,
        0,
        0,
        rssi,
        100,
        0,
    ];
    frame(TYPE_LINK_STATISTICS, &payload)
}

/// What a whole frame (`b`, CRC checked) says.
fn event(b: &[u8]) -> Option<RcEvent> {
    let payload = &b[3..b.len() - 1];
    match (b[2], payload.len()) {
        (TYPE_RC_CHANNELS_PACKED, RC_PAYLOAD) => {
            let mut packed = [0u8; RC_PAYLOAD];
            packed.copy_from_slice(payload);
            Some(RcEvent::Channels(RcFrame {
                channels: unpack_channels(&packed),
                frame_lost: false,
                failsafe: false,
            }))
        }
        (TYPE_LINK_STATISTICS, LINK_PAYLOAD) => {
            let antenna = usize::from(payload[4] & 1);
            Some(RcEvent::Link(LinkStats {
                rssi_dbm: -i16::from(payload[antenna]),
                link_quality_pct: payload[2],
                snr_db: payload[3] as i8,
            }))
        }
        _ => None,
    }
}

/// CRSF bytes in, frames out, whatever the bytes' split.
#[derive(Debug, Clone, Default)]
pub struct CrsfDecoder {
    buf: Vec<u8>,
    stats: DecoderStats,
}

impl CrsfDecoder {
    pub fn new() -> Self {
        CrsfDecoder {
            buf: Vec::with_capacity(FRAME_MAX),
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

    /// Takes `bytes`, appending what each frame completed says to `out`. Less than a frame
    /// stays buffered, starting with an address byte.
    pub fn feed(&mut self, bytes: &[u8], out: &mut Vec<RcEvent>) {
        for &b in bytes {
            if self.buf.is_empty() && !is_address(b) {
                self.stats.discarded_bytes += 1;
                continue;
            }
            self.buf.push(b);
            self.scan(out);
        }
    }

    /// Takes every frame the buffer completes; a bad candidate's first byte is dropped and
    /// the search goes on from the next address byte.
    fn scan(&mut self, out: &mut Vec<RcEvent>) {
        while self.buf.len() >= 2 {
            let len = usize::from(self.buf[1]);
            let whole = len + 2;
            if (2..=FRAME_MAX - 2).contains(&len) && self.buf.len() < whole {
                return;
            }
            let good = (2..=FRAME_MAX - 2).contains(&len)
                && crc8(&self.buf[2..whole - 1]) == self.buf[whole - 1];
            if good {
                match event(&self.buf[..whole]) {
                    Some(e) => {
                        if matches!(e, RcEvent::Channels(_)) {
                            self.stats.frames += 1;
                        } else {
                            self.stats.other_frames += 1;
                        }
                        out.push(e);
                    }
                    None => self.stats.other_frames += 1,
                }
                self.buf.drain(..whole);
            } else {
                self.stats.rejected_frames += 1;
                self.buf.remove(0);
                self.stats.discarded_bytes += 1;
            }
            let skip = self
                .buf
                .iter()
                .position(|&b| is_address(b))
                .unwrap_or(self.buf.len());
            self.stats.discarded_bytes += skip as u64;
            self.buf.drain(..skip);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// RC frames captured from a receiver and the channels Betaflight decodes from them
    /// (betaflight/betaflight, src/test/unit/rx_crsf_unittest.cc, `capturedData`, test
    /// `TestCapturedData`): address 0x00, CRC 0x6C and 0x94.
    const CAPTURED: [([u8; 26], [u16; 4]); 2] = [
        (
            [
                0x00, 0x18, 0x16, 0xBD, 0x08, 0x9F, 0xF4, 0xAE, 0xF7, 0xBD, 0xEF, 0x7D, 0xEF, 0xFB,
                0xAD, 0xFD, 0x45, 0x2B, 0x5A, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x6C,
            ],
            [189, 993, 978, 983],
        ),
        (
            [
                0x00, 0x18, 0x16, 0xBD, 0x08, 0x9F, 0xF4, 0xAA, 0xF7, 0xBD, 0xEF, 0x7D, 0xEF, 0xFB,
                0xAD, 0xFD, 0x45, 0x2B, 0x5A, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x94,
            ],
            [189, 993, 978, 981],
        ),
    ];

    /// Betaflight's unit test of the unpacking (`TestCrsfFrameStatusUnpacking`): payload
    /// bytes and the channels they hold.
    const UNPACKING: ([u8; 11], [u16; 8]) = (
        [
            0xFF, 0xFF, 0x00, 0x00, 0x58, 0x01, 0x00, 0xf0, 0x01, 0x60, 0xe2,
        ],
        [0x7ff, 0x1f, 0, 172, 0, 992, 0, 1811],
    );

    /// A command frame (baud rate negotiation, type 0x32) from the same tests: a good frame
    /// of a type not read.
    const COMMAND: [u8; 14] = [
        0xC8, 0x0C, 0x32, 0xC8, 0xEC, 0x0A, 0x70, 0x01, 0x00, 0x1E, 0x84, 0x80, 0x22, 0x72,
    ];

    fn decode(bytes: &[u8]) -> (Vec<RcEvent>, DecoderStats) {
        let mut d = CrsfDecoder::new();
        let mut out = Vec::new();
        d.feed(bytes, &mut out);
        (out, d.stats())
    }

    #[test]
    fn captured_frames_decode_as_betaflight_decodes_them() {
        for (bytes, want) in CAPTURED {
            let (out, stats) = decode(&bytes);
            assert_eq!(stats.frames, 1, "{bytes:02x?}");
            let RcEvent::Channels(f) = out[0] else {
                panic!("{out:?}")
            };
            assert_eq!(f.channels[..4], want);
            assert_eq!(encode_channels(&f.channels)[1..], bytes[1..], "re-encoded");
        }
        let mut payload = [0u8; 22];
        payload[..11].copy_from_slice(&UNPACKING.0);
        assert_eq!(unpack_channels(&payload)[..8], UNPACKING.1);
        let (out, stats) = decode(&COMMAND);
        assert_eq!(
            (out.len(), stats.other_frames, stats.rejected_frames),
            (0, 1, 0)
        );
    }

    #[test]
    fn link_statistics_and_channels_are_found_after_noise_and_a_bad_crc() {
        let link = LinkStats {
            rssi_dbm: -67,
            link_quality_pct: 98,
            snr_db: -3,
        };
        let channels: [u16; 16] = std::array::from_fn(|k| 172 + 109 * k as u16);
        let mut bad = encode_channels(&channels);
        bad[10] ^= 0x40;
        let mut stream = vec![0xc8, 0x00, 0xc8, 0x3f, 0x55];
        stream.extend(&bad);
        stream.extend(encode_link(&link));
        stream.extend(encode_channels(&channels));
        for split in [1, 3, 26, stream.len()] {
            let mut d = CrsfDecoder::new();
            let mut out = Vec::new();
            for chunk in stream.chunks(split) {
                d.feed(chunk, &mut out);
            }
            let want = [
                RcEvent::Link(link),
                RcEvent::Channels(RcFrame {
                    channels,
                    frame_lost: false,
                    failsafe: false,
                }),
            ];
            assert_eq!(out, want, "split {split}");
            assert!(d.stats().rejected_frames >= 1, "{:?}", d.stats());
        }
    }
}
