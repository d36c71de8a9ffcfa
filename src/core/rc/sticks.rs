//! A receiver's channels read as the pilot's sticks and switches (spec: none; PX4's RC_MAP_*
//! and RCn_MIN/TRIM/MAX/REV/DZ, ArduPilot's RCMAP_* and RCn_*): each function on its
//! channel, through that channel's calibrated range, its direction and its deadband.

use super::{CHANNELS, RcFrame};

/// Where a function is and how its channel's travel is read (the `rc.*` tables).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ChannelCal {
    /// 1 to 16.
    pub channel: u8,
    /// The channel's ticks at its two ends and at rest (a stick centred; a switch's middle).
    pub min: u16,
    pub center: u16,
    pub max: u16,
    /// The channel moves the other way.
    pub reversed: bool,
    /// Around the centre, this share of the half travel reads 0 (a stick's rest).
    pub deadband: f64,
}

impl ChannelCal {
    /// A stick or a switch on `channel`, calibrated to the protocols' nominal range.
    pub const fn nominal(channel: u8, deadband: f64) -> Self {
        ChannelCal {
            channel,
            min: 172,
            center: super::TICKS_MID,
            max: 1811,
            reversed: false,
            deadband,
        }
    }

    /// The channel in `f` read as −1 (min) … 0 (center) … 1 (max), reversed if it is, its
    /// deadband taken out (the rest scaled to the whole travel). A channel out of the frame's
    /// range reads 0.
    pub fn read(&self, f: &RcFrame) -> f64 {
        let Some(&ticks) = f.channels.get(usize::from(self.channel).wrapping_sub(1)) else {
            return 0.0;
        };
        let (v, c) = (f64::from(ticks), f64::from(self.center));
        let half = if v >= c {
            f64::from(self.max) - c
        } else {
            c - f64::from(self.min)
        };
        let x = if half > 0.0 {
            ((v - c) / half).clamp(-1.0, 1.0)
        } else {
            0.0
        };
        let x = if self.reversed { -x } else { x };
        let db = self.deadband.clamp(0.0, 0.99);
        if x.abs() <= db {
            0.0
        } else {
            x.signum() * (x.abs() - db) / (1.0 - db)
        }
    }

    /// A two-position switch: on in the upper half of its travel.
    pub fn on(&self, f: &RcFrame) -> bool {
        self.read(f) > 0.0
    }

    /// A switch of `n` positions (or a knob): which one, 0-based from the low end, the
    /// travel split into `n` equal bands.
    pub fn position(&self, f: &RcFrame, n: usize) -> usize {
        if n <= 1 {
            return 0;
        }
        let x = (self.read(f) + 1.0) / 2.0;
        ((x * n as f64) as usize).min(n - 1)
    }

    /// The ticks that read `x` (−1 … 1) on this channel, deadband included: what a simulated
    /// transmitter sends for a stick at `x`.
    pub fn ticks_for(&self, x: f64) -> u16 {
        let db = self.deadband.clamp(0.0, 0.99);
        let x = x.clamp(-1.0, 1.0);
        let x = if x == 0.0 {
            0.0
        } else {
            x.signum() * (x.abs() * (1.0 - db) + db)
        };
        let x = if self.reversed { -x } else { x };
        let c = f64::from(self.center);
        let t = if x >= 0.0 {
            c + x * (f64::from(self.max) - c)
        } else {
            c + x * (c - f64::from(self.min))
        };
        t.round().clamp(0.0, f64::from(super::TICKS_MAX)) as u16
    }
}

/// The sticks, each −1 … 1: roll right, pitch forward (nose down), yaw right positive;
/// throttle −1 low, 1 high.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Sticks {
    pub roll: f64,
    pub pitch: f64,
    pub yaw: f64,
    pub throttle: f64,
}

/// Every function's channel, and how many positions the mode switch has.
#[derive(Debug, Clone, PartialEq)]
pub struct RcMap {
    pub roll: ChannelCal,
    pub pitch: ChannelCal,
    pub yaw: ChannelCal,
    pub throttle: ChannelCal,
    pub arm: ChannelCal,
    pub kill: ChannelCal,
    pub mode: ChannelCal,
    /// Positions of the mode switch (1 to 6).
    pub mode_positions: usize,
}

/// A frame as the pilot meant it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RcInput {
    pub sticks: Sticks,
    pub arm: bool,
    pub kill: bool,
    /// The mode switch's position, 0-based.
    pub mode: usize,
}

impl RcMap {
    pub fn read(&self, f: &RcFrame) -> RcInput {
        RcInput {
            sticks: Sticks {
                roll: self.roll.read(f),
                pitch: self.pitch.read(f),
                yaw: self.yaw.read(f),
                throttle: self.throttle.read(f),
            },
            arm: self.arm.on(f),
            kill: self.kill.on(f),
            mode: self.mode.position(f, self.mode_positions),
        }
    }

    /// The channels a transmitter sends for `input` (the simulated transmitter's; channels no
    /// function uses at their centre).
    pub fn frame_for(&self, input: &RcInput) -> [u16; CHANNELS] {
        let mut ch = [super::TICKS_MID; CHANNELS];
        let mut set = |cal: &ChannelCal, x: f64| {
            if let Some(c) = ch.get_mut(usize::from(cal.channel).wrapping_sub(1)) {
                *c = cal.ticks_for(x);
            }
        };
        let s = &input.sticks;
        set(&self.roll, s.roll);
        set(&self.pitch, s.pitch);
        set(&self.yaw, s.yaw);
        set(&self.throttle, s.throttle);
        set(&self.arm, if input.arm { 1.0 } else { -1.0 });
        set(&self.kill, if input.kill { 1.0 } else { -1.0 });
        let n = self.mode_positions.max(1) as f64;
        set(&self.mode, (input.mode as f64 + 0.5) / n * 2.0 - 1.0);
        ch
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cal(channel: u8) -> ChannelCal {
        ChannelCal {
            channel,
            min: 172,
            center: 992,
            max: 1811,
            reversed: false,
            deadband: 0.05,
        }
    }

    fn map() -> RcMap {
        RcMap {
            roll: cal(1),
            pitch: cal(2),
            throttle: cal(3),
            yaw: cal(4),
            arm: cal(5),
            kill: cal(6),
            mode: cal(7),
            mode_positions: 6,
        }
    }

    fn frame(channels: [u16; CHANNELS]) -> RcFrame {
        RcFrame {
            channels,
            frame_lost: false,
            failsafe: false,
        }
    }

    #[test]
    fn sticks_read_through_their_range_direction_and_deadband() {
        let mut ch = [992; CHANNELS];
        ch[0] = 1811;
        ch[1] = 172;
        ch[2] = 1000;
        ch[3] = 992 + 410;
        let f = frame(ch);
        let m = map();
        let s = m.read(&f).sticks;
        assert_eq!(
            (s.roll, s.pitch, s.throttle),
            (1.0, -1.0, 0.0),
            "ends; 8 ticks in the deadband"
        );
        assert!((s.yaw - (0.5 - 0.05) / 0.95).abs() < 1e-3, "{}", s.yaw);
        let reversed = ChannelCal {
            reversed: true,
            ..m.roll
        };
        assert_eq!(reversed.read(&f), -1.0);
        // An uneven calibration: each half scaled on its own.
        let uneven = ChannelCal {
            min: 500,
            center: 1000,
            max: 2000,
            deadband: 0.0,
            ..m.roll
        };
        let mut c = [1000; CHANNELS];
        c[0] = 750;
        assert_eq!(uneven.read(&frame(c)), -0.5);
        c[0] = 1500;
        assert_eq!(uneven.read(&frame(c)), 0.5);
        // A channel outside 1–16, or a calibration of no travel, reads 0.
        assert_eq!(
            ChannelCal {
                channel: 0,
                ..m.roll
            }
            .read(&f),
            0.0
        );
        assert_eq!(ChannelCal { max: 992, ..m.roll }.read(&f), 0.0);
    }

    #[test]
    fn switches_and_the_mode_bands_and_what_a_transmitter_sends_for_them() {
        let m = map();
        for mode in 0..6 {
            for (arm, kill) in [(false, false), (true, false), (false, true)] {
                let input = RcInput {
                    sticks: Sticks {
                        roll: 0.3,
                        pitch: -0.7,
                        yaw: 0.0,
                        throttle: -1.0,
                    },
                    arm,
                    kill,
                    mode,
                };
                let got = m.read(&frame(m.frame_for(&input)));
                assert_eq!((got.arm, got.kill, got.mode), (arm, kill, mode));
                let s = got.sticks;
                assert!(
                    (s.roll - 0.3).abs() < 2e-3 && (s.pitch + 0.7).abs() < 2e-3,
                    "{s:?}"
                );
                assert_eq!((s.yaw, s.throttle), (0.0, -1.0));
            }
        }
        // A three-position switch read in three bands: low, middle, high.
        let mut ch = [992; CHANNELS];
        ch[6] = 172;
        assert_eq!(m.mode.position(&frame(ch), 3), 0);
        ch[6] = 992;
        assert_eq!(m.mode.position(&frame(ch), 3), 1);
        ch[6] = 1811;
        assert_eq!(m.mode.position(&frame(ch), 3), 2);
    }
}
