//! MAVLink 2 message signing (mavlink.io's "Message Signing"): with `gcs.signing_key_file`
//! set, every frame sent carries a signature and only frames signed with the same key, newer
//! than the last one of their stream, are taken; unsigned and badly signed ones are counted
//! and dropped before they are read.
//!
//! The signature is the first 6 bytes of SHA-256 over the 32-byte key and the frame from its
//! start byte through the link id and the 48-bit timestamp (10 µs units since 1 January
//! 2015). The key comes from `gcs.signing_key_file` ([`crate::config::signing_key`]).

use sha2::{Digest, Sha256};
use std::collections::HashMap;

/// Bytes of a signature block: link id, timestamp, signature.
pub const BLOCK_LEN: usize = 13;
const SIGNATURE_LEN: usize = 6;
/// A new stream older than the newest timestamp seen by more than this is refused (a replay
/// of recorded frames), in 10 µs units: one minute, as the specification says.
const NEW_STREAM_SLACK: u64 = 60 * 100_000;
/// Streams (link id, system, component) remembered; a new one beyond takes the place of the
/// stalest.
const STREAMS_MAX: usize = 64;

/// The key and the replay guard of one link.
#[derive(Clone)]
pub struct Signing {
    key: [u8; 32],
    /// The newest timestamp known: the clock's at the start ([`Signing::since`]), then the
    /// newest seen (receiving) or sent.
    newest: u64,
    /// The last timestamp of each stream that signed validly.
    streams: HashMap<(u8, u8, u8), u64>,
}

/// Never the key: a debug print of the link's state must not give it away.
impl std::fmt::Debug for Signing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Signing")
            .field("key", &"(secret)")
            .field("newest", &self.newest)
            .field("streams", &self.streams.len())
            .finish()
    }
}

impl Signing {
    pub fn new(key: [u8; 32]) -> Self {
        Signing {
            key,
            newest: 0,
            streams: HashMap::with_capacity(4),
        }
    }

    /// Known to be at least `now` (10 µs units since 2015): a new stream more than a minute
    /// older is a recording. A board whose clock starts at 1970 until set gets no such guard
    /// for new streams until a signed frame has been heard (a stream's own frames must
    /// still grow).
    pub fn since(mut self, now: u64) -> Self {
        self.newest = now;
        self
    }

    fn signature(&self, signed_part: &[u8]) -> [u8; SIGNATURE_LEN] {
        let digest = Sha256::new()
            .chain_update(self.key)
            .chain_update(signed_part)
            .finalize();
        let mut s = [0u8; SIGNATURE_LEN];
        s.copy_from_slice(&digest[..SIGNATURE_LEN]);
        s
    }

    /// Whether `frame` (a whole signed MAVLink 2 frame, its checksum checked) is signed with
    /// this key, newer than its stream's last frame: then that stream's time moves on.
    pub fn verify(&mut self, frame: &[u8]) -> bool {
        let Some(split) = frame.len().checked_sub(SIGNATURE_LEN + 7) else {
            return false;
        };
        let (signed_part, block) = frame.split_at(frame.len() - SIGNATURE_LEN);
        let link_id = frame[split];
        let mut ts = [0u8; 8];
        ts[..6].copy_from_slice(&frame[split + 1..split + 7]);
        let timestamp = u64::from_le_bytes(ts);
        let stream = (link_id, frame[5], frame[6]);
        let fresh = match self.streams.get(&stream) {
            Some(&last) => timestamp > last,
            None => timestamp + NEW_STREAM_SLACK >= self.newest,
        };
        if !fresh || self.signature(signed_part) != block {
            return false;
        }
        if self.streams.len() >= STREAMS_MAX && !self.streams.contains_key(&stream) {
            let stalest = self
                .streams
                .iter()
                .min_by_key(|(_, t)| **t)
                .map(|(k, _)| *k);
            if let Some(k) = stalest {
                self.streams.remove(&k);
            }
        }
        self.streams.insert(stream, timestamp);
        self.newest = self.newest.max(timestamp);
        true
    }

    /// Signs the unsigned MAVLink 2 frame in `frame` (from its start byte) at `now`
    /// (10 µs units since 2015, later than any earlier signature): sets the signed flag,
    /// recomputes the checksum with `crc_extra`, appends link id 0, timestamp and signature.
    pub fn sign(&mut self, frame: &mut Vec<u8>, crc_extra: u8, now: u64) {
        if frame.len() < 12 {
            return;
        }
        frame[2] |= 0x01;
        let end = frame.len() - 2;
        let crc = mavlink::calculate_crc(&frame[1..end], crc_extra);
        frame[end..].copy_from_slice(&crc.to_le_bytes());
        self.newest = now.max(self.newest + 1);
        frame.push(0);
        frame.extend_from_slice(&self.newest.to_le_bytes()[..6]);
        let s = self.signature(frame);
        frame.extend_from_slice(&s);
    }
}

/// The signing clock now: 10 µs units since 1 January 2015 (0 before it).
pub fn now() -> u64 {
    let since_epoch_us = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros());
    (since_epoch_us.saturating_sub(1_420_070_400_000_000) / 10)
        .try_into()
        .unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gcs::wire::Encoder;
    use mavlink::dialects::common::{HEARTBEAT_DATA, MavMessage};
    use mavlink::{MavHeader, Message};

    fn signed_heartbeat(s: &mut Signing, now: u64) -> Vec<u8> {
        signed_from(s, now, 255)
    }

    fn signed_from(s: &mut Signing, now: u64, system_id: u32) -> Vec<u8> {
        let mut frame = Vec::new();
        let msg = MavMessage::HEARTBEAT(HEARTBEAT_DATA::DEFAULT);
        let header = MavHeader {
            system_id,
            ..MavHeader::default()
        };
        let _ = mavlink::write_v2_msg(&mut frame, header, &msg);
        s.sign(&mut frame, MavMessage::extra_crc(msg.message_id()), now);
        frame
    }

    #[test]
    fn a_signed_frame_verifies_once_and_a_forged_or_old_one_never() {
        let key = crate::config::signing_key("correct horse\n").unwrap();
        let mut sender = Signing::new(key);
        let mut receiver = Signing::new(key);
        let frame = signed_heartbeat(&mut sender, 1_000_000);
        assert!(receiver.verify(&frame));
        assert!(!receiver.verify(&frame), "a replayed frame is old");
        let newer = signed_heartbeat(&mut sender, 1_000_000);
        let mut forged = newer.clone();
        let last = forged.len() - 1;
        forged[last] ^= 1;
        assert!(!receiver.verify(&forged));
        assert!(receiver.verify(&newer), "its timestamp moved on");
        let mut stranger = Signing::new(crate::config::signing_key("other").unwrap());
        assert!(!receiver.verify(&signed_heartbeat(&mut stranger, 2_000_000)));
        // A new stream more than a minute older than the newest time known is a recording,
        // from the start on (the clock's time): validly signed, still refused.
        let mut fresh = Signing::new(key).since(10_000_000);
        let recorded = signed_from(&mut Signing::new(key), 1, 9);
        assert!(!fresh.verify(&recorded));
        let recent = signed_from(&mut Signing::new(key), 9_000_000, 9);
        assert!(fresh.verify(&recent), "within the minute");
        // The decoder's frames carry the block: a whole encoded frame verifies.
        let mut enc = Encoder::new(1, 1).with_signing(Signing::new(key));
        let mut out = Vec::new();
        enc.encode(&MavMessage::HEARTBEAT(HEARTBEAT_DATA::DEFAULT), &mut out);
        assert!(Signing::new(key).verify(&out));
    }

    #[test]
    fn a_debug_print_never_shows_the_key() {
        let s = Signing::new([0xab; 32]);
        let text = format!("{s:?}");
        assert!(!text.contains("171") && !text.contains("ab, ab"), "{text}");
        assert!(text.contains("(secret)"), "{text}");
    }

    #[test]
    fn keys_are_passphrases_or_hexadecimal() {
        let hex = "00".repeat(31) + "ff";
        let key = crate::config::signing_key(&hex).unwrap();
        assert_eq!(key[31], 0xff);
        // MAVProxy's `signing setup pass`: the passphrase's SHA-256.
        assert_eq!(
            crate::config::signing_key("pass\n").unwrap(),
            <[u8; 32]>::from(Sha256::digest(b"pass"))
        );
        assert!(crate::config::signing_key("\n").is_err());
    }
}
