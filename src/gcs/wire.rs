//! MAVLink framing: bytes from a link into checked messages, with every byte that is not one
//! counted by why; messages into MAVLink 2 frames.
//!
//! The crate's readers skip bad frames silently; a vehicle must say how much of what it heard
//! was noise, so the framing is done here and only the message definitions, CRC_EXTRA and the
//! payload codecs are the crate's. MAVLink 1 frames are accepted (pymavlink and older ground
//! stations start with them); every frame sent is MAVLink 2.

use super::signing::{self, Signing};
use mavlink::dialects::common::MavMessage;
use mavlink::{MavHeader, MavlinkVersion, Message};

const STX_V1: u8 = 0xFE;
const STX_V2: u8 = 0xFD;
/// Bytes before the payload: STX and header (v1: 6, v2: 10).
const HEAD_V1: usize = 6;
const HEAD_V2: usize = 10;
const CRC_LEN: usize = 2;
const SIGNATURE_LEN: usize = 13;
/// A signed MAVLink 2 frame (incompat flag 1).
const IFLAG_SIGNED: u8 = 0x01;
/// Bytes held waiting for a frame's end; beyond this the oldest count as garbage (a serial
/// link that never completes a frame cannot grow the buffer).
const MAX_PENDING: usize = 4096;

/// What became of the bytes heard, by kind.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct RxCounts {
    /// Frames whose checksum matched and whose payload decoded.
    pub frames: u64,
    /// Bytes outside any frame (noise, a lost frame's start).
    pub garbage_bytes: u64,
    /// Frames whose checksum did not match.
    pub bad_crc: u64,
    /// Frames cut short (a datagram ending inside a frame).
    pub truncated: u64,
    /// Frames of a message id this dialect does not have (their checksum cannot be checked).
    pub unknown: u64,
    /// Frames whose checksum matched but whose payload did not decode (an enum out of range).
    pub malformed: u64,
    /// With signing on (`gcs.signing_key_file`): frames without a signature (MAVLink 1's
    /// included), and frames whose signature is wrong or old (another key, a replay).
    pub unsigned: u64,
    pub bad_signature: u64,
}

/// A checked message and who sent it.
#[derive(Debug, Clone)]
pub struct Received {
    pub header: MavHeader,
    pub version: MavlinkVersion,
    pub msg: MavMessage,
}

/// Splits bytes into messages: feed it with [`Decoder::push`], take messages with
/// [`Decoder::next_message`] until it has none. Each byte is looked at as a frame's start at
/// most once (a cursor, not a shifting buffer), so noise costs at most one checksum per
/// byte that looks like a start.
#[derive(Debug, Default)]
pub struct Decoder {
    buf: Vec<u8>,
    /// Where the bytes not yet looked at begin.
    at: usize,
    /// Each push is a whole datagram (UDP): a frame it ends inside is cut short, never
    /// continued by the next. Otherwise a byte stream (a serial radio).
    datagrams: bool,
    /// This datagram's cut frame is counted (its later bytes are noise).
    cut_counted: bool,
    pub counts: RxCounts,
    /// Signing on: only validly signed frames are messages.
    signing: Option<Signing>,
}

/// One step of the decoder over its buffer. Returned once per frame and never stored, so
/// its size does not matter.
#[allow(clippy::large_enum_variant)]
enum Step {
    /// More bytes are needed.
    Wait,
    /// Drop this many bytes and go on (a message found or not).
    Skip(usize, Option<Received>),
}

impl Decoder {
    pub fn for_datagrams() -> Self {
        Decoder {
            datagrams: true,
            ..Decoder::default()
        }
    }

    pub fn for_stream() -> Self {
        Decoder::default()
    }

    /// Only frames signed with `signing`'s key are taken.
    pub fn with_signing(mut self, signing: Signing) -> Self {
        self.signing = Some(signing);
        self
    }

    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.drain(..self.at);
        self.at = 0;
        if self.datagrams {
            // What the previous datagram left was not taken: it is lost.
            self.counts.garbage_bytes += self.buf.len() as u64;
            self.buf.clear();
            self.cut_counted = false;
        }
        self.buf.extend_from_slice(bytes);
        if self.buf.len() > MAX_PENDING {
            let excess = self.buf.len() - MAX_PENDING;
            self.counts.garbage_bytes += excess as u64;
            self.buf.drain(..excess);
        }
    }

    /// A stream whose bytes stopped inside a claimed frame: its start is taken for noise
    /// (skipped and counted) so the bytes behind it are read. True when there was one.
    pub fn skip_stalled_start(&mut self) -> bool {
        if self.at >= self.buf.len() {
            return false;
        }
        self.counts.garbage_bytes += 1;
        self.at += 1;
        true
    }

    /// The next message in the bytes pushed so far, if a whole one is there.
    pub fn next_message(&mut self) -> Option<Received> {
        loop {
            match self.step() {
                Step::Wait => return None,
                Step::Skip(n, found) => {
                    self.at += n;
                    if found.is_some() {
                        return found;
                    }
                }
            }
        }
    }

    fn step(&mut self) -> Step {
        let rest = &self.buf[self.at..];
        if rest.is_empty() {
            return Step::Wait;
        }
        let Some(start) = rest.iter().position(|&b| b == STX_V1 || b == STX_V2) else {
            self.counts.garbage_bytes += rest.len() as u64;
            return Step::Skip(rest.len(), None);
        };
        if start > 0 {
            self.counts.garbage_bytes += start as u64;
            return Step::Skip(start, None);
        }
        let v2 = rest[0] == STX_V2;
        let head = if v2 { HEAD_V2 } else { HEAD_V1 };
        if rest.len() < head {
            return self.incomplete();
        }
        let payload_len = usize::from(rest[1]);
        let signed = v2 && rest[2] & IFLAG_SIGNED != 0;
        let len = head + payload_len + CRC_LEN + if signed { SIGNATURE_LEN } else { 0 };
        if rest.len() < len {
            return self.incomplete();
        }
        self.check(v2, head, payload_len, len)
    }

    /// A frame begun at the cursor is not all there: more bytes will come on a stream; in a
    /// datagram it was cut short (counted once; or its start was noise: look further in).
    fn incomplete(&mut self) -> Step {
        if !self.datagrams {
            return Step::Wait;
        }
        if self.cut_counted {
            self.counts.garbage_bytes += 1;
        } else {
            self.counts.truncated += 1;
            self.cut_counted = true;
        }
        Step::Skip(1, None)
    }

    /// A whole frame at the cursor: its flags, its checksum, then its message.
    fn check(&mut self, v2: bool, head: usize, payload_len: usize, len: usize) -> Step {
        let b = &self.buf[self.at..];
        let msg_id = if v2 {
            u32::from_le_bytes([b[7], b[8], b[9], 0])
        } else {
            u32::from(b[5])
        };
        // A flag this decoder does not know changes the frame's layout (MAVLink 2 says to
        // drop it); an unknown id cannot have its checksum checked. Either is a frame only
        // when another frame (or the end) follows it; otherwise its start was noise.
        let unknown_flags = v2 && b[2] & !IFLAG_SIGNED != 0;
        if unknown_flags || MavMessage::default_message_from_id(msg_id).is_none() {
            if b.len() == len && !self.datagrams {
                // On a stream the next byte decides.
                return Step::Wait;
            }
            if b.len() == len || matches!(b[len], STX_V1 | STX_V2) {
                self.counts.unknown += 1;
                return Step::Skip(len, None);
            }
            self.counts.garbage_bytes += 1;
            return Step::Skip(1, None);
        }
        let end = head + payload_len;
        let crc = u16::from_le_bytes([b[end], b[end + 1]]);
        if mavlink::calculate_crc(&b[1..end], MavMessage::extra_crc(msg_id)) != crc {
            // Resynchronise inside the frame: its start may have been noise.
            self.counts.bad_crc += 1;
            return Step::Skip(1, None);
        }
        if let Some(signing) = self.signing.as_mut() {
            let signed = v2 && b[2] & IFLAG_SIGNED != 0;
            if !signed {
                self.counts.unsigned += 1;
                return Step::Skip(len, None);
            }
            if !signing.verify(&b[..len]) {
                self.counts.bad_signature += 1;
                return Step::Skip(len, None);
            }
        }
        let (version, header) = header_of(v2, b);
        match MavMessage::parse(version, msg_id, &b[head..end]) {
            Ok(msg) => {
                self.counts.frames += 1;
                let r = Received {
                    header,
                    version,
                    msg,
                };
                Step::Skip(len, Some(r))
            }
            Err(_) => {
                self.counts.malformed += 1;
                Step::Skip(len, None)
            }
        }
    }
}

/// A checked frame's version and sender.
fn header_of(v2: bool, b: &[u8]) -> (MavlinkVersion, MavHeader) {
    if v2 {
        let h = MavHeader {
            system_id: u32::from(b[5]),
            component_id: b[6],
            sequence: b[4],
        };
        (MavlinkVersion::V2, h)
    } else {
        let h = MavHeader {
            system_id: u32::from(b[3]),
            component_id: b[4],
            sequence: b[2],
        };
        (MavlinkVersion::V1, h)
    }
}

/// Writes MAVLink 2 frames from one system and component, numbering them (and signing them
/// when signing is on).
#[derive(Debug, Clone)]
pub struct Encoder {
    pub system_id: u8,
    pub component_id: u8,
    sequence: u8,
    signing: Option<Signing>,
}

impl Encoder {
    pub fn new(system_id: u8, component_id: u8) -> Self {
        Encoder {
            system_id,
            component_id,
            sequence: 0,
            signing: None,
        }
    }

    /// Every frame signed with `signing`'s key.
    pub fn with_signing(mut self, signing: Signing) -> Self {
        self.signing = Some(signing);
        self
    }

    /// `msg` as one frame appended to `out`, signed (with a key) at the signing clock's now.
    pub fn encode(&mut self, msg: &MavMessage, out: &mut Vec<u8>) {
        self.encode_at(msg, out, signing::now());
    }

    /// `msg` as one frame appended to `out`, signed (with a key) at `signing_now` (10 µs units
    /// since 2015): the caller's clock, so a protocol that never reads one can sign.
    pub fn encode_at(&mut self, msg: &MavMessage, out: &mut Vec<u8>, signing_now: u64) {
        let header = MavHeader {
            system_id: u32::from(self.system_id),
            component_id: self.component_id,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        let start = out.len();
        // Writing into a Vec cannot fail.
        let _ = mavlink::write_v2_msg(out, header, msg);
        if let Some(signing) = self.signing.as_mut() {
            let mut frame = out.split_off(start);
            signing.sign(
                &mut frame,
                MavMessage::extra_crc(msg.message_id()),
                signing_now,
            );
            out.extend_from_slice(&frame);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::{HEARTBEAT_DATA, MavMessage};

    fn heartbeat_frame(seq_from: &mut Encoder) -> Vec<u8> {
        let mut out = Vec::new();
        seq_from.encode(&MavMessage::HEARTBEAT(HEARTBEAT_DATA::DEFAULT), &mut out);
        out
    }

    fn drain(d: &mut Decoder) -> Vec<Received> {
        std::iter::from_fn(|| d.next_message()).collect()
    }

    #[test]
    fn frames_round_trip_and_noise_is_counted_by_kind() {
        let mut enc = Encoder::new(1, 1);
        let good = heartbeat_frame(&mut enc);
        let mut d = Decoder::for_datagrams();
        // Noise, a good frame, a frame with a flipped CRC byte, another good frame.
        let mut bad = heartbeat_frame(&mut enc);
        let last = bad.len() - 1;
        bad[last] ^= 0xFF;
        let mut bytes = b"noise".to_vec();
        bytes.extend_from_slice(&good);
        bytes.extend_from_slice(&bad);
        bytes.extend_from_slice(&good);
        d.push(&bytes);
        let got = drain(&mut d);
        assert_eq!(got.len(), 2);
        assert!(matches!(got[0].msg, MavMessage::HEARTBEAT(_)));
        assert_eq!(got[0].header.system_id, 1);
        assert_eq!(d.counts.frames, 2);
        assert_eq!(d.counts.bad_crc, 1);
        // "noise" and the bad frame's bytes after its start (skipped one by one; a byte of
        // it that looks like a frame's start may count as a cut frame instead).
        let c = d.counts;
        assert_eq!(c.garbage_bytes + c.truncated, 5 + bad.len() as u64 - 1);
    }

    #[test]
    fn a_frame_cut_short_waits_on_a_stream_and_counts_in_a_datagram() {
        let good = heartbeat_frame(&mut Encoder::new(1, 1));
        let mut d = Decoder::for_stream();
        d.push(&good[..7]);
        assert!(d.next_message().is_none());
        d.push(&good[7..]);
        assert!(d.next_message().is_some());
        let mut d = Decoder::for_datagrams();
        d.push(&good[..7]);
        assert!(d.next_message().is_none());
        d.push(&good);
        assert!(d.next_message().is_some());
        assert_eq!(d.counts.truncated, 1);
        assert_eq!(d.counts.frames, 1);
    }

    #[test]
    fn unknown_ids_and_endless_noise_are_counted_and_bounded() {
        let mut frame = heartbeat_frame(&mut Encoder::new(1, 1));
        frame[7] = 0xFF; // message id 0xFF0000-ish: not in the dialect
        frame[9] = 0xFF;
        // On a stream, the byte after it decides that it was a frame (here: another start).
        let mut d = Decoder::for_stream();
        d.push(&frame);
        assert!(d.next_message().is_none());
        assert_eq!(d.counts.unknown, 0);
        d.push(&[STX_V2]);
        assert!(d.next_message().is_none());
        assert_eq!(d.counts.unknown, 1);
        // A claimed frame that never ends holds at most MAX_PENDING bytes; good frames after
        // the noise come through once the last claim is complete and fails its checksum.
        for _ in 0..100 {
            d.push(&[STX_V2, 255, 0, 0, 0, 0, 0, 0, 0, 0]);
            d.push(&[0u8; 100]);
            assert!(d.next_message().is_none());
        }
        assert!(d.counts.garbage_bytes > 5000, "{:?}", d.counts);
        let good = heartbeat_frame(&mut Encoder::new(1, 1));
        for _ in 0..20 {
            d.push(&good);
        }
        assert!(d.next_message().is_some(), "{:?}", d.counts);
    }

    #[test]
    fn a_stalled_stream_gives_up_a_claimed_frame_for_the_frames_behind_it() {
        let good = heartbeat_frame(&mut Encoder::new(1, 1));
        // A stray start claiming 255 bytes of a known id, then one real frame, then silence.
        let mut bytes = vec![STX_V2, 255, 0, 0, 0, 0, 0, 0, 0, 0];
        bytes.extend_from_slice(&good);
        let mut d = Decoder::for_stream();
        d.push(&bytes);
        assert!(d.next_message().is_none());
        assert!(d.skip_stalled_start());
        assert!(d.next_message().is_some(), "{:?}", d.counts);
        assert!(!d.skip_stalled_start());
    }

    #[test]
    fn a_stray_start_with_an_unknown_id_does_not_swallow_the_frames_after_it() {
        let good = heartbeat_frame(&mut Encoder::new(1, 1));
        // A start byte, then a header claiming an unknown id and 20 bytes, then a real frame.
        let mut bytes = vec![STX_V2, 20, 0, 0, 0, 0, 0, 0xEE, 0xEE, 0xEE];
        bytes.extend_from_slice(&good);
        bytes.extend_from_slice(&[0u8; 30]);
        let mut d = Decoder::for_stream();
        d.push(&bytes);
        assert!(d.next_message().is_some(), "{:?}", d.counts);
        assert_eq!(d.counts.unknown, 0);
    }

    #[test]
    fn mavlink_1_frames_are_read() {
        let mut out = Vec::new();
        let header = MavHeader {
            system_id: 255,
            component_id: 190,
            sequence: 7,
        };
        mavlink::write_v1_msg(
            &mut out,
            header,
            &MavMessage::HEARTBEAT(HEARTBEAT_DATA::DEFAULT),
        )
        .unwrap();
        let mut d = Decoder::for_datagrams();
        d.push(&out);
        let got = d.next_message().unwrap();
        assert_eq!(got.version, MavlinkVersion::V1);
        assert_eq!(got.header, header);
    }
}
