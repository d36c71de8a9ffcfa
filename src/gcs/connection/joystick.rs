//! A ground station's joystick (MANUAL_CONTROL): its axes as the pilot's sticks, the same
//! path the radio's take (`position`, `altitude`; `hold` ignores them, as PX4's Hold does).
//! x is the pitch stick (forward +), y the roll (right +), r the yaw (clockwise +), each
//! −1000…1000, and z the throttle, 0…1000 with 500 its centre (QGroundControl's and PX4's
//! reading: the message's own text says r counter-clockwise positive, but QGroundControl
//! sends and PX4 reads a yaw stick right as positive, and so does uquad); an axis sent as INT16_MAX (the message's "unused") reads centred. A stream is
//! thinned to changes of [`STEP`] and a keep-alive every [`EVERY`], so mode.log records the
//! moves, not the stream; a stream that stops centres the sticks after
//! `commander::sticks::GCS_STICKS_S`: the vehicle holds.

use super::Connection;
use crate::core::commander::OperatorInput;
use mavlink::dialects::common::MANUAL_CONTROL_DATA;
use std::time::{Duration, Instant};

/// Sticks are taken to this resolution (a share of their half travel).
pub const STEP: f64 = 0.01;
/// Unchanged sticks are passed on this often: the flight hears the joystick is there.
pub const EVERY: Duration = Duration::from_millis(200);

/// The sticks last passed on, and when.
#[derive(Debug, Default)]
pub(super) struct Joystick {
    last: Option<(Instant, [f64; 4])>,
}

/// The sticks (roll, pitch, yaw, throttle; each −1…1, throttle −1 low) of a MANUAL_CONTROL.
pub fn sticks_of(m: &MANUAL_CONTROL_DATA) -> [f64; 4] {
    let axis = |v: i16, centre: f64, half: f64| {
        if v == i16::MAX {
            return 0.0;
        }
        let s = ((f64::from(v) - centre) / half).clamp(-1.0, 1.0);
        (s / STEP).round() * STEP
    };
    [
        axis(m.y, 0.0, 1000.0),
        axis(m.x, 0.0, 1000.0),
        axis(m.r, 0.0, 1000.0),
        axis(m.z, 500.0, 500.0),
    ]
}

impl Connection {
    /// MANUAL_CONTROL from a sender that may command: its sticks passed on when they move
    /// or [`EVERY`] anyway.
    pub(super) fn on_manual_control(&mut self, now: Instant, m: &MANUAL_CONTROL_DATA) {
        let sticks = sticks_of(m);
        let due = self
            .joystick
            .last
            .is_none_or(|(at, last)| last != sticks || now.saturating_duration_since(at) >= EVERY);
        if !due {
            return;
        }
        self.joystick.last = Some((now, sticks));
        self.counts.sticks_taken += 1;
        self.operator.push_back(OperatorInput::Sticks(sticks));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axes_read_as_the_clients_send_them() {
        let m = |x, y, z, r| MANUAL_CONTROL_DATA {
            x,
            y,
            z,
            r,
            ..MANUAL_CONTROL_DATA::DEFAULT
        };
        assert_eq!(sticks_of(&m(0, 0, 500, 0)), [0.0, 0.0, 0.0, 0.0]);
        assert_eq!(sticks_of(&m(1000, -1000, 1000, 500)), [-1.0, 1.0, 0.5, 1.0]);
        assert_eq!(
            sticks_of(&m(0, 0, 0, 0))[3],
            -1.0,
            "z 0 is the throttle low"
        );
        assert_eq!(
            sticks_of(&m(i16::MAX, i16::MAX, i16::MAX, i16::MAX)),
            [0.0; 4]
        );
        assert_eq!(sticks_of(&m(-30000, 30000, -5, 7)), [1.0, -1.0, 0.01, -1.0]);
    }
}
