//! Position targets a companion computer streams (SET_POSITION_TARGET_LOCAL_NED,
//! SET_POSITION_TARGET_GLOBAL_INT): in `hold` each moves the hold point, as the commander's
//! `move X Y Z` (from the takeoff point; the fence and the manual heights refuse what they
//! do not allow, in the commander's words; the commander refuses it unless it holds, so a
//! target that crosses a landing or a return never undoes it); in any other mode they are
//! ignored and counted
//! (PX4 takes them only in its Offboard mode). The position is taken, velocities,
//! accelerations and yaw are not (a target that gives no position is ignored). A stream is
//! thinned to what moves the point by [`MIN_MOVE_M`] at most every [`EVERY`], so mode.log
//! records the moves, not the stream; a stream that stops leaves the vehicle holding its last
//! point.

use super::Connection;
use crate::core::commander::{Command, LinkSource, Mode, OperatorInput};
use mavlink::dialects::common::*;
use std::time::{Duration, Instant};

/// A target closer than this to the last one taken is not a move, m.
pub const MIN_MOVE_M: f64 = 0.05;
/// Targets are taken at most this often.
pub const EVERY: Duration = Duration::from_millis(200);

/// The last target taken (its time and its point in the estimate's frame, north-west-up).
#[derive(Debug, Default)]
pub(super) struct Guided {
    last: Option<(Instant, [f64; 3])>,
}

/// The position bits of a type mask: none ignored.
fn has_position(mask: PositionTargetTypemask) -> bool {
    let position = PositionTargetTypemask::POSITION_TARGET_TYPEMASK_X_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_Y_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_Z_IGNORE;
    !mask.intersects(position)
}

impl Connection {
    /// SET_POSITION_TARGET_LOCAL_NED: north-east-down, from the local frame's origin
    /// (MAV_FRAME_LOCAL_NED) or from where the vehicle is (MAV_FRAME_LOCAL_OFFSET_NED).
    pub(super) fn on_local_target(&mut self, now: Instant, t: SET_POSITION_TARGET_LOCAL_NED_DATA) {
        let here = self.status.live.map(|l| [l.x[0], l.x[1], l.x[2]]);
        let ned = [f64::from(t.x), f64::from(t.y), f64::from(t.z)];
        let nwu = [ned[0], -ned[1], -ned[2]];
        let point = match t.coordinate_frame {
            MavFrame::MAV_FRAME_LOCAL_NED => Some(nwu),
            MavFrame::MAV_FRAME_LOCAL_OFFSET_NED => {
                here.map(|h| std::array::from_fn(|i| h[i] + nwu[i]))
            }
            _ => None,
        };
        self.guided_target(now, point.filter(|_| has_position(t.type_mask)));
    }

    /// SET_POSITION_TARGET_GLOBAL_INT: latitude and longitude, the altitude above the
    /// takeoff point (MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) or above sea level
    /// (MAV_FRAME_GLOBAL_INT), placed by the newest fix.
    pub(super) fn on_global_target(
        &mut self,
        now: Instant,
        t: SET_POSITION_TARGET_GLOBAL_INT_DATA,
    ) {
        let (Some(fix), Some(live)) = (self.status.fix, self.status.live) else {
            return self.guided_target(now, None);
        };
        let deg = [f64::from(t.lat_int) / 1e7, f64::from(t.lon_int) / 1e7];
        let off = crate::core::gps::offset_m([fix.fix.lat_deg, fix.fix.lon_deg], deg);
        let xy = [fix.sample.xy_m[0] + off[0], fix.sample.xy_m[1] + off[1]];
        let home_z = live.home_m.map_or(0.0, |h| h[2]);
        // The `_INT` frames (superseded by the plain ones, which mean the same here) are what
        // most senders still use.
        #[allow(deprecated)]
        let z = match (t.coordinate_frame, fix.fix.alt_m, fix.sample.z_m) {
            (
                MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
                | MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT,
                _,
                _,
            ) => Some(home_z + f64::from(t.alt)),
            (MavFrame::MAV_FRAME_GLOBAL_INT | MavFrame::MAV_FRAME_GLOBAL, Some(alt), Some(z)) => {
                Some(z + f64::from(t.alt) - alt)
            }
            _ => None,
        };
        let point = z.map(|z| [xy[0], xy[1], z]);
        self.guided_target(now, point.filter(|_| has_position(t.type_mask)));
    }

    /// A target point in the estimate's frame (none: not one this link takes): in `hold`, a
    /// move of the hold point, thinned; otherwise ignored and counted.
    fn guided_target(&mut self, now: Instant, point: Option<[f64; 3]>) {
        let live = self.status.live;
        let holding = self.status.mode == Mode::Hold && live.is_some_and(|l| l.mode == Mode::Hold);
        if !holding {
            // A hold entered again starts from its own point: the next target is a move.
            self.guided.last = None;
        }
        let (Some(point), true, Some(live)) = (point, holding, live) else {
            self.counts.targets_ignored += 1;
            return;
        };
        let fresh = self.guided.last.is_none_or(|(at, last)| {
            let moved = (0..3)
                .map(|i| (point[i] - last[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            now.saturating_duration_since(at) >= EVERY && moved >= MIN_MOVE_M
        });
        if !fresh || point.iter().any(|v| !v.is_finite()) {
            return;
        }
        self.guided.last = Some((now, point));
        self.counts.targets_taken += 1;
        let home = live.home_m.unwrap_or_default();
        let from_home: [f64; 3] = std::array::from_fn(|i| point[i] - home[i]);
        self.operator.push_back(OperatorInput::Command(
            Command::Move(from_home),
            LinkSource::Gcs,
        ));
    }
}
