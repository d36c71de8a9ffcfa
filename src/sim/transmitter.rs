//! The simulated transmitter and receiver: the pilot's sticks and switches as the script moves
//! them (`sticks R P Y T`, `switch arm|kill on|off`, `switch mode NAME`), sent as real SBUS or
//! CRSF frames and read back through the same decoder and map as `fly`'s RC task reads a
//! board's UART. `--inject rc-loss@T` makes the receiver give up: an SBUS receiver sends
//! frames with its failsafe flag, a CRSF receiver stops sending.

use crate::config::{RcConfig, RcProtocol};
use crate::core::commander::OperatorInput;
use crate::core::rc::link::{RcLink, RcMode};
use crate::core::rc::sticks::{RcInput, Sticks};
use crate::core::rc::{Decoder, LinkStats, RcEvent, RcFrame, crsf, sbus};
use std::collections::VecDeque;

/// A move of the pilot's hands at a simulated time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RcMove {
    /// Roll, pitch, yaw, throttle, each −1…1 (throttle −1 is low).
    Sticks([f64; 4]),
    Arm(bool),
    Kill(bool),
    Mode(RcMode),
}

impl RcMove {
    /// `sticks R P Y T`, `switch arm on|off`, `switch kill on|off`, `switch mode NAME`; `None`
    /// when `text` is none of these words (a command, then).
    pub fn parse(text: &str) -> Option<Result<RcMove, String>> {
        let words: Vec<&str> = text.split_whitespace().collect();
        match words.first() {
            Some(&"sticks") => Some(sticks(&words[1..])),
            Some(&"switch") => Some(switch(&words[1..])),
            _ => None,
        }
    }
}

fn sticks(args: &[&str]) -> Result<RcMove, String> {
    let v: Vec<f64> = args
        .iter()
        .map(|a| a.parse::<f64>().ok().filter(|x| (-1.0..=1.0).contains(x)))
        .collect::<Option<_>>()
        .filter(|v: &Vec<f64>| v.len() == 4)
        .ok_or("sticks takes ROLL PITCH YAW THROTTLE, each from -1 to 1 (throttle -1 is low)")?;
    Ok(RcMove::Sticks([v[0], v[1], v[2], v[3]]))
}

fn switch(args: &[&str]) -> Result<RcMove, String> {
    let on = |w: &str| match w {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("switch: {w:?} is not on or off")),
    };
    match args {
        ["arm", w] => on(w).map(RcMove::Arm),
        ["kill", w] => on(w).map(RcMove::Kill),
        ["mode", name] => {
            let modes = [
                RcMode::Position,
                RcMode::Altitude,
                RcMode::Hold,
                RcMode::Mission,
                RcMode::Return,
                RcMode::Land,
            ];
            modes
                .into_iter()
                .find(|m| m.name() == *name)
                .map(RcMove::Mode)
                .ok_or_else(|| {
                    format!("switch mode: {name:?} is not position, altitude, hold, mission, return or land")
                })
        }
        _ => Err("switch takes arm on|off, kill on|off or mode NAME".into()),
    }
}

/// The transmitter, the air between and the receiver, up to the decoded inputs.
#[derive(Debug)]
pub struct Transmitter {
    protocol: RcProtocol,
    hands: RcInput,
    moves: VecDeque<(i64, RcMove)>,
    /// `rc-loss`: the receiver gives up from this time on.
    lost_from_us: Option<i64>,
    period_us: i64,
    next_us: i64,
    decoder: Decoder,
    link: RcLink,
    /// The mode switch's position, by mode (a mode the switch does not have leaves it).
    positions: Vec<RcMode>,
    events: Vec<RcEvent>,
}

impl Transmitter {
    /// With a receiver configured (`rc.protocol`), a transmitter whose pilot makes `moves`;
    /// the sticks centred, the throttle low, the switches off, the mode switch at its first
    /// position.
    pub fn new(
        rc: &RcConfig,
        timeout_s: f64,
        moves: &[(i64, RcMove)],
        lost_from_us: Option<i64>,
    ) -> Option<Self> {
        let period_us = match rc.protocol {
            RcProtocol::None => return None,
            // A high-speed SBUS receiver's 7 ms; ExpressLRS at 250 Hz.
            RcProtocol::Sbus => 7_000,
            RcProtocol::Crsf => 4_000,
        };
        let decoder = Decoder::new(rc.protocol);
        Some(Transmitter {
            protocol: rc.protocol,
            hands: RcInput {
                sticks: Sticks {
                    throttle: -1.0,
                    ..Sticks::default()
                },
                arm: false,
                kill: false,
                mode: 0,
            },
            moves: moves.iter().copied().collect(),
            lost_from_us,
            period_us,
            next_us: 0,
            decoder,
            link: RcLink::new(rc.map(), rc.modes.clone(), timeout_s),
            positions: rc.modes.clone(),
            events: Vec::new(),
        })
    }

    /// The frames due by `t_us`: sent, received and read; the inputs they make, stamped with
    /// their frame's time, into `out`. Whether the last frame read has the kill switch on
    /// (the caller stops the motors at once, as `fly`'s RC task does); none when no frame
    /// was read.
    pub fn due(&mut self, t_us: i64, out: &mut Vec<(i64, OperatorInput)>) -> Option<bool> {
        let mut kill = None;
        for (at, bytes) in self.frames_due(t_us) {
            self.events.clear();
            self.decoder.feed(&bytes, &mut self.events);
            let mut inputs = Vec::new();
            for e in &self.events {
                match e {
                    RcEvent::Channels(f) => kill = Some(self.link.frame(f, at, &mut inputs)),
                    RcEvent::Link(stats) => self.link.link(stats, &mut inputs),
                }
            }
            out.extend(inputs.into_iter().map(|i| (at, i)));
        }
        kill
    }

    /// The bytes of the frames due by `t_us`, as the receiver puts them on its UART
    /// (`--realtime`: written into a pty that `fly`'s RC reader reads).
    pub fn air_due(&mut self, t_us: i64) -> Vec<u8> {
        self.frames_due(t_us)
            .into_iter()
            .flat_map(|(_, bytes)| bytes)
            .collect()
    }

    /// Each frame period due by `t_us`: the pilot's moves made by then, and what reaches the
    /// UART, with its time (a lost CRSF receiver's periods send nothing).
    fn frames_due(&mut self, t_us: i64) -> Vec<(i64, Vec<u8>)> {
        let mut frames = Vec::new();
        while self.next_us <= t_us {
            let at = self.next_us;
            self.next_us += self.period_us;
            while let Some(&(when, m)) = self.moves.front()
                && when <= at
            {
                self.moves.pop_front();
                self.apply(m);
            }
            if let Some(bytes) = self.air(at) {
                frames.push((at, bytes));
            }
        }
        frames
    }

    /// The radio as a watcher sees it (a paced run's link and console).
    pub fn status(&self) -> Option<crate::core::status::RcStatus> {
        self.link.status()
    }

    /// What the receiver's decoder made of the frames (the lock-step modes'; nothing is
    /// dropped between it and the flight).
    pub fn counts(&self) -> crate::core::rc::RcCounts {
        let d = self.decoder.stats();
        crate::core::rc::RcCounts {
            frames: d.frames,
            discarded_bytes: d.discarded_bytes,
            rejected_frames: d.rejected_frames,
            dropped_inputs: 0,
        }
    }

    fn apply(&mut self, m: RcMove) {
        match m {
            RcMove::Sticks([roll, pitch, yaw, throttle]) => {
                self.hands.sticks = Sticks {
                    roll,
                    pitch,
                    yaw,
                    throttle,
                }
            }
            RcMove::Arm(on) => self.hands.arm = on,
            RcMove::Kill(on) => self.hands.kill = on,
            RcMove::Mode(mode) => {
                if let Some(p) = self.positions.iter().position(|&x| x == mode) {
                    self.hands.mode = p;
                }
            }
        }
    }

    /// What reaches the UART at `at_us`: the frame of the pilot's hands, a receiver's
    /// failsafe frame, or (a CRSF receiver that lost its transmitter) nothing.
    fn air(&self, at_us: i64) -> Option<Vec<u8>> {
        let lost = self.lost_from_us.is_some_and(|l| at_us >= l);
        let channels = self.link.map().frame_for(&self.hands);
        match (self.protocol, lost) {
            (RcProtocol::Crsf, true) | (RcProtocol::None, _) => None,
            (RcProtocol::Sbus, lost) => Some(
                sbus::encode(&RcFrame {
                    channels,
                    frame_lost: lost,
                    failsafe: lost,
                })
                .to_vec(),
            ),
            (RcProtocol::Crsf, false) => {
                let mut b = crsf::encode_channels(&channels);
                // The receiver's link statistics, ten a second.
                if at_us % 100_000 < self.period_us {
                    b.extend(crsf::encode_link(&LinkStats {
                        rssi_dbm: -60,
                        link_quality_pct: 100,
                        snr_db: 10,
                    }));
                }
                Some(b)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::commander::LinkSource;

    #[test]
    fn moves_parse_and_others_are_commands() {
        assert_eq!(
            RcMove::parse("sticks 0.5 -1 0 1"),
            Some(Ok(RcMove::Sticks([0.5, -1.0, 0.0, 1.0])))
        );
        assert_eq!(
            RcMove::parse("switch kill on"),
            Some(Ok(RcMove::Kill(true)))
        );
        assert_eq!(
            RcMove::parse("switch mode land"),
            Some(Ok(RcMove::Mode(RcMode::Land)))
        );
        assert!(matches!(RcMove::parse("sticks 2 0 0 0"), Some(Err(_))));
        assert!(matches!(RcMove::parse("switch arm maybe"), Some(Err(_))));
        assert!(matches!(RcMove::parse("switch mode acro"), Some(Err(_))));
        assert_eq!(RcMove::parse("arm"), None);
    }

    #[test]
    fn both_protocols_carry_the_switches_and_a_loss_is_the_receivers_way() {
        for protocol in [RcProtocol::Sbus, RcProtocol::Crsf] {
            let rc = RcConfig {
                protocol,
                ..RcConfig::default()
            };
            let moves = [
                (1_000_000, RcMove::Arm(true)),
                (2_000_000, RcMove::Mode(RcMode::Land)),
                (3_000_000, RcMove::Kill(true)),
            ];
            let mut tx = Transmitter::new(&rc, 0.5, &moves, Some(4_000_000)).unwrap();
            let mut out = Vec::new();
            let (mut kills, mut on) = (Vec::new(), false);
            for t in (0..=5_000_000).step_by(1000) {
                if let Some(kill) = tx.due(t, &mut out) {
                    if kill && !on {
                        kills.push(t);
                    }
                    on = kill;
                }
            }
            let commands: Vec<String> = out
                .iter()
                .filter_map(|(_, i)| match i {
                    OperatorInput::Command(c, LinkSource::Rc) => Some(c.to_string()),
                    _ => None,
                })
                .collect();
            assert_eq!(commands, ["arm", "land"], "{protocol:?}");
            assert_eq!(kills.len(), 1, "{protocol:?}");
            assert!(kills[0] >= 3_000_000 && kills[0] < 3_010_000, "{kills:?}");
            let lost = out
                .iter()
                .any(|(_, i)| matches!(i, OperatorInput::Rc(r) if r.lost));
            // SBUS: the receiver's failsafe flag; CRSF: silence (the commander's timeout).
            assert_eq!(lost, protocol == RcProtocol::Sbus, "{protocol:?}");
            let last = out.iter().map(|(t, _)| *t).max().unwrap_or(0);
            assert!(
                last < 4_000_000 + 7_000,
                "nothing heard after the loss: {last}"
            );
        }
    }
}
