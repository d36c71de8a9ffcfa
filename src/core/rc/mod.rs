//! A hobby RC receiver's serial protocols, decoded (spec: none; the original had no radio):
//! SBUS ([`sbus`]) and CRSF ([`crsf`], ExpressLRS and TBS Crossfire). Each decoder takes the
//! UART's bytes as they come, finds its frames again after noise or a cut, and gives
//! [`RcEvent`]s: the 16 channels in the protocols' common 11-bit ticks (172 ≈ 988 µs, 992 the
//! centre, 1811 ≈ 2012 µs), with the receiver's own failsafe flags, and (CRSF) the link's
//! quality. Pure: no clock, no I/O.

pub mod crsf;
pub mod link;
pub mod sbus;
pub mod sticks;

/// The receiver's protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RcProtocol {
    /// No receiver (the default): the vehicle is flown by typed commands and ground stations.
    None,
    /// SBUS: 100 000 baud, 8E2, inverted.
    Sbus,
    /// CRSF (ExpressLRS, TBS Crossfire): 420 000 baud, 8N1.
    Crsf,
}

/// Channels a frame carries.
pub const CHANNELS: usize = 16;
/// The largest 11-bit channel value.
pub const TICKS_MAX: u16 = 0x7ff;
/// The centre of a stick's travel, ticks (1500 µs).
pub const TICKS_MID: u16 = 992;

/// A channel's ticks as the pulse width a PWM receiver would give, µs (172 → 988, 992 → 1500,
/// 1811 → 2012: 5/8 µs a tick, as the protocols define it).
pub fn ticks_to_us(ticks: u16) -> u16 {
    let us = 1500.0 + (f64::from(ticks) - f64::from(TICKS_MID)) * 0.625;
    us.round().clamp(0.0, f64::from(u16::MAX)) as u16
}

/// One frame of channels, as the receiver sent it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RcFrame {
    /// Channels 1–16, 11-bit ticks.
    pub channels: [u16; CHANNELS],
    /// The receiver says this frame was not received from the transmitter (SBUS's frame-lost
    /// flag): the channels are the last good ones.
    pub frame_lost: bool,
    /// The receiver is in its failsafe (SBUS's failsafe flag): the transmitter is gone.
    pub failsafe: bool,
}

/// The radio link as the receiver measures it (CRSF's LINK_STATISTICS, uplink).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkStats {
    /// The active antenna's signal strength, dBm.
    pub rssi_dbm: i16,
    /// Packets received of the last 100, %.
    pub link_quality_pct: u8,
    pub snr_db: i8,
}

/// What a decoder found in the bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RcEvent {
    Channels(RcFrame),
    Link(LinkStats),
}

/// What a decoder has seen: frames taken, and bytes it could not place in a frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Frames of channels taken.
    pub frames: u64,
    /// Other frames taken (CRSF's link statistics, frame types not read).
    pub other_frames: u64,
    /// Bytes dropped while looking for a frame's start.
    pub discarded_bytes: u64,
    /// Candidates whose end marker or CRC was wrong.
    pub rejected_frames: u64,
}

/// What the RC receiver's bytes gave: frames of channels, bytes outside any frame, candidates
/// refused (end byte, CRC), and inputs the flight's queue had no room for.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct RcCounts {
    pub frames: u64,
    pub discarded_bytes: u64,
    pub rejected_frames: u64,
    pub dropped_inputs: u64,
}

/// 16 channels of 11 bits packed least significant bit first (SBUS's and CRSF's layout).
pub fn unpack_channels(packed: &[u8; 22]) -> [u16; CHANNELS] {
    std::array::from_fn(|ch| {
        let bit = ch * 11;
        let (byte, shift) = (bit / 8, bit % 8);
        let mut v = u32::from(packed[byte]) >> shift;
        v |= u32::from(packed[byte + 1]) << (8 - shift);
        if shift > 5 {
            v |= u32::from(packed[byte + 2]) << (16 - shift);
        }
        (v & u32::from(TICKS_MAX)) as u16
    })
}

/// The inverse of [`unpack_channels`]; values above 11 bits are cut to their low 11 bits.
pub fn pack_channels(channels: &[u16; CHANNELS]) -> [u8; 22] {
    let mut out = [0u8; 22];
    for (ch, &v) in channels.iter().enumerate() {
        let v = u32::from(v & TICKS_MAX);
        let bit = ch * 11;
        let (byte, shift) = (bit / 8, bit % 8);
        let bits = v << shift;
        out[byte] |= bits as u8;
        out[byte + 1] |= (bits >> 8) as u8;
        if shift > 5 {
            out[byte + 2] |= (bits >> 16) as u8;
        }
    }
    out
}

/// A byte stream's decoder, of either protocol.
#[derive(Debug, Clone)]
pub enum Decoder {
    Sbus(sbus::SbusDecoder),
    Crsf(crsf::CrsfDecoder),
}

impl Decoder {
    /// The decoder of `protocol` (SBUS's for none: it then reads nothing it is given).
    pub fn new(protocol: RcProtocol) -> Self {
        match protocol {
            RcProtocol::Crsf => Decoder::Crsf(crsf::CrsfDecoder::new()),
            RcProtocol::Sbus | RcProtocol::None => Decoder::Sbus(sbus::SbusDecoder::new()),
        }
    }

    /// Takes `bytes`, appending what completes to `out`.
    pub fn feed(&mut self, bytes: &[u8], out: &mut Vec<RcEvent>) {
        match self {
            Decoder::Sbus(d) => d.feed(bytes, out),
            Decoder::Crsf(d) => d.feed(bytes, out),
        }
    }

    pub fn stats(&self) -> DecoderStats {
        match self {
            Decoder::Sbus(d) => d.stats(),
            Decoder::Crsf(d) => d.stats(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_read_as_the_protocols_pulse_widths() {
        assert_eq!(
            [172, 992, 1811, 0, TICKS_MAX].map(ticks_to_us),
            [988, 1500, 2012, 880, 2159]
        );
    }

    #[test]
    fn channels_pack_and_unpack_as_eleven_bit_fields() {
        let channels: [u16; CHANNELS] = std::array::from_fn(|k| (k as u16 * 131 + 7) & TICKS_MAX);
        assert_eq!(unpack_channels(&pack_channels(&channels)), channels);
        let mut one = [0u16; CHANNELS];
        one[1] = 1;
        let packed = pack_channels(&one);
        assert_eq!(packed[1], 0b0000_1000, "channel 2 starts at bit 11");
    }
}
