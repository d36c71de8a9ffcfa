//! A ground station's mission (MISSION_ITEM_INT, or the older MISSION_ITEM) turned into a
//! mission file's text (`config/missions/`'s format), which the link writes into the run
//! folder and loads as `--mission` files are: one loader, one check, and a replay that plans
//! the same mission from the same file. Pure.
//!
//! - NAV_TAKEOFF → `takeoff` to z (m above the takeoff point; first item only);
//! - NAV_WAYPOINT → `goto` (param 1 > 0 adds a `hold` of that many seconds);
//! - NAV_LOITER_TURNS → `orbit` of param 1 turns, radius |param 3| (positive: clockwise,
//!   seen from above, i.e. to the right), centred on x, y; a change of height first climbs
//!   or descends where the vehicle is;
//! - NAV_RETURN_TO_LAUNCH → `return`; NAV_LAND → `land` (at x, y when they are given);
//! - DO_CHANGE_SPEED → the speed (param 2, m/s) of the items after it.
//!
//! Frames: GLOBAL_RELATIVE_ALT(_INT) (latitude, longitude, height above the takeoff point),
//! LOCAL_NED (metres north, east, down in the frame LOCAL_POSITION_NED reports), MISSION (no
//! position). Latitude and longitude are placed from the newest fix on a sphere, as
//! GLOBAL_POSITION_INT reports them (a real receiver's local frame follows the UTM grid, a
//! fraction of a degree from true north: centimetres over a few metres).

use crate::core::gps::offset_m;
// Older ground stations still send the superseded MISSION_ITEM: it is taken.
#[allow(deprecated)]
use mavlink::dialects::common::MISSION_ITEM_DATA;
use mavlink::dialects::common::{MISSION_ITEM_INT_DATA, MavCmd, MavFrame};
use mavlink::dialects::common::{MavMissionResult, MavMissionType};
use std::fmt::Write;

/// The most items one upload may hold.
pub const MAX_ITEMS: u16 = 500;

/// Where the local frame sits on the Earth, for items given in latitude and longitude: a fix
/// in both frames, and the takeoff point (or, on the ground, where the vehicle is).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Anchor {
    /// The fix: latitude, longitude (degrees) and its position in the local frame (x north,
    /// y west), m.
    pub fix_deg: Option<[f64; 2]>,
    pub fix_xy_m: [f64; 2],
    /// The takeoff point in the local frame (x, y, z), m: LOCAL_NED items are given in the
    /// frame LOCAL_POSITION_NED reports, and a mission's points are from the takeoff point.
    pub home_m: [f64; 3],
}

impl Anchor {
    /// The anchor of an upload: the newest `fix`; the takeoff point `home_m` once there is
    /// one, else where the vehicle is: by its estimate `estimate_m`, or, before the estimate
    /// runs, at the fix's x, y on the ground, z 0 — the estimate's height starts at the ground
    /// it is calibrated on, so LOCAL_POSITION_NED will read 0 there whatever the receiver's
    /// altitude says (taking the fix's z offset LOCAL_NED heights by its error, metres).
    pub fn of(
        fix: Option<&crate::core::gps::LiveFix>,
        estimate_m: Option<[f64; 3]>,
        home_m: Option<[f64; 3]>,
    ) -> Anchor {
        let on_ground = fix.map(|f| [f.sample.xy_m[0], f.sample.xy_m[1], 0.0]);
        Anchor {
            fix_deg: fix.map(|f| [f.fix.lat_deg, f.fix.lon_deg]),
            fix_xy_m: fix.map_or([0.0; 2], |f| f.sample.xy_m),
            home_m: home_m.or(estimate_m).or(on_ground).unwrap_or_default(),
        }
    }
}

/// An upload as a mission file: its text, and for each of the file's items the upload's
/// sequence number it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct Converted {
    pub text: String,
    pub seq_of_item: Vec<u16>,
}

/// An item refused: the result to acknowledge with, and why (names the item's sequence
/// number).
pub type Refusal = (MavMissionResult, String);

/// An older MISSION_ITEM (floating-point coordinates) as a MISSION_ITEM_INT; coordinates that
/// are not numbers refused (as integers they would read as 0: the origin, and be flown).
#[allow(deprecated)]
pub fn item_int(i: &MISSION_ITEM_DATA) -> Result<MISSION_ITEM_INT_DATA, Refusal> {
    for (v, name, result) in [
        (i.x, "x", MavMissionResult::MAV_MISSION_INVALID_PARAM5_X),
        (i.y, "y", MavMissionResult::MAV_MISSION_INVALID_PARAM6_Y),
    ] {
        if !v.is_finite() && i.frame != MavFrame::MAV_FRAME_MISSION {
            return Err((result, format!("mission item {}: {name} is {v}", i.seq)));
        }
    }
    let global = matches!(
        i.frame,
        MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT
            | MavFrame::MAV_FRAME_GLOBAL
            | MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
            | MavFrame::MAV_FRAME_GLOBAL_INT
    );
    let scale = if global { 1e7 } else { 1e4 };
    let int = |v: f32| (f64::from(v) * scale).round().clamp(-2.1e9, 2.1e9) as i32;
    Ok(MISSION_ITEM_INT_DATA {
        param1: i.param1,
        param2: i.param2,
        param3: i.param3,
        param4: i.param4,
        x: int(i.x),
        y: int(i.y),
        z: i.z,
        seq: i.seq,
        command: i.command,
        target_system: i.target_system,
        target_component: i.target_component,
        frame: i.frame,
        current: i.current,
        autocontinue: i.autocontinue,
        mission_type: MavMissionType::MAV_MISSION_TYPE_MISSION,
    })
}

/// What one item says about position: x, y from the takeoff point (none: not given) and the
/// height above it (none: not given), m.
struct Place {
    xy_m: Option<[f64; 2]>,
    z_m: Option<f64>,
}

#[allow(deprecated)]
fn place(i: &MISSION_ITEM_INT_DATA, at: &Anchor) -> Result<Place, Refusal> {
    let seq = i.seq;
    let z = f64::from(i.z);
    // Not a number is MAVLink's "not given" for a height (the item keeps the one before; an
    // item that needs one, a takeoff, is refused for having none); an infinite one is no
    // height at all.
    if z.is_infinite() {
        return Err((
            MavMissionResult::MAV_MISSION_INVALID_PARAM7,
            format!("mission item {seq}: z is {z}"),
        ));
    }
    let z_m = z.is_finite().then_some(z);
    let given = i.x != 0 || i.y != 0;
    match i.frame {
        MavFrame::MAV_FRAME_MISSION => Ok(Place {
            xy_m: None,
            z_m: None,
        }),
        MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT | MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT => {
            let xy_m = if given {
                let Some(fix_deg) = at.fix_deg else {
                    return Err((
                        MavMissionResult::MAV_MISSION_DENIED,
                        format!(
                            "mission item {seq}: latitude and longitude, but no GPS fix to \
                             place them: wait for a fix, or use MAV_FRAME_LOCAL_NED"
                        ),
                    ));
                };
                let to = [f64::from(i.x) / 1e7, f64::from(i.y) / 1e7];
                let [n, w] = offset_m(fix_deg, to);
                Some([
                    at.fix_xy_m[0] + n - at.home_m[0],
                    at.fix_xy_m[1] + w - at.home_m[1],
                ])
            } else {
                None
            };
            Ok(Place { xy_m, z_m })
        }
        MavFrame::MAV_FRAME_LOCAL_NED => Ok(Place {
            // North, east, down in the local frame to north, west, up from the takeoff point.
            xy_m: Some([
                f64::from(i.x) / 1e4 - at.home_m[0],
                -f64::from(i.y) / 1e4 - at.home_m[1],
            ]),
            z_m: z_m.map(|z| -z - at.home_m[2]),
        }),
        f => Err((
            MavMissionResult::MAV_MISSION_UNSUPPORTED_FRAME,
            format!(
                "mission item {seq}: frame {f:?} not supported (GLOBAL_RELATIVE_ALT_INT, \
                 LOCAL_NED, MISSION)"
            ),
        )),
    }
}

/// Builds the file item by item, keeping where the vehicle will be (none: somewhere on an
/// orbit, or wherever a mission without a takeoff is started) and the speed.
struct Writer {
    text: String,
    seq_of_item: Vec<u16>,
    xy_m: Option<[f64; 2]>,
    z_m: f64,
    speed_m_s: f64,
}

impl Writer {
    fn item(&mut self, seq: u16, body: std::fmt::Arguments<'_>) {
        let _ = write!(self.text, "\n[[item]]  # upload item {seq}\n{body}");
        self.seq_of_item.push(seq);
    }

    fn goto(&mut self, seq: u16, xy_m: [f64; 2], z_m: f64) {
        let speed = self.speed_m_s;
        let [x, y] = xy_m;
        self.item(
            seq,
            format_args!(
                "kind = \"goto\"\nat_m = [{x:?}, {y:?}, {z_m:?}]\nspeed_m_s = {speed:?}\n"
            ),
        );
        self.xy_m = Some(xy_m);
        self.z_m = z_m;
    }
}

/// The upload `items` (in order, sequence numbers 0..) as a mission file, placed with `at`;
/// `speed_m_s` until a DO_CHANGE_SPEED; `hover_z_m` is where a mission without a takeoff
/// starts from. Values the file's checks would refuse (heights, the fence) are left to them.
pub fn convert(
    items: &[MISSION_ITEM_INT_DATA],
    at: &Anchor,
    speed_m_s: f64,
    hover_z_m: f64,
) -> Result<Converted, Refusal> {
    let mut w = Writer {
        text: format!("# A ground station's mission: {} items.\n", items.len()),
        seq_of_item: Vec::new(),
        xy_m: None,
        z_m: hover_z_m,
        speed_m_s,
    };
    for i in items {
        write_item(&mut w, i, at)?;
    }
    Ok(Converted {
        text: w.text,
        seq_of_item: w.seq_of_item,
    })
}

/// An item refused as not valid, naming it.
fn invalid(i: &MISSION_ITEM_INT_DATA, what: &str) -> Result<(), Refusal> {
    Err((
        MavMissionResult::MAV_MISSION_INVALID,
        format!("mission item {} ({:?}): {what}", i.seq, i.command),
    ))
}

fn write_item(w: &mut Writer, i: &MISSION_ITEM_INT_DATA, at: &Anchor) -> Result<(), Refusal> {
    let seq = i.seq;
    let p = place(i, at)?;
    let z = p.z_m.unwrap_or(w.z_m);
    match i.command {
        MavCmd::MAV_CMD_NAV_TAKEOFF => {
            let Some(z) = p.z_m else {
                return invalid(i, "no height (z)");
            };
            w.item(seq, format_args!("kind = \"takeoff\"\nheight_m = {z:?}\n"));
            (w.xy_m, w.z_m) = (Some([0.0, 0.0]), z);
        }
        MavCmd::MAV_CMD_NAV_WAYPOINT => {
            let Some(xy) = p.xy_m else {
                return invalid(i, "no position (x, y)");
            };
            w.goto(seq, xy, z);
            let hold_s = f64::from(i.param1);
            if !hold_s.is_finite() {
                return invalid(i, "hold time (param 1) is not a number");
            }
            if hold_s > 0.0 {
                w.item(seq, format_args!("kind = \"hold\"\nseconds = {hold_s:?}\n"));
            }
        }
        MavCmd::MAV_CMD_NAV_LOITER_TURNS => return orbit(w, i, p.xy_m, z),
        MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH => {
            w.item(seq, format_args!("kind = \"return\"\n"));
            w.xy_m = Some([0.0, 0.0]);
        }
        MavCmd::MAV_CMD_NAV_LAND => {
            if let Some(xy) = p.xy_m {
                w.goto(seq, xy, w.z_m);
            }
            w.item(seq, format_args!("kind = \"land\"\n"));
        }
        MavCmd::MAV_CMD_DO_CHANGE_SPEED => return change_speed(w, i),
        c => {
            return Err((
                MavMissionResult::MAV_MISSION_UNSUPPORTED,
                format!(
                    "mission item {seq}: {c:?} not supported (NAV_TAKEOFF, NAV_WAYPOINT, \
                     NAV_LOITER_TURNS, NAV_RETURN_TO_LAUNCH, NAV_LAND, DO_CHANGE_SPEED)"
                ),
            ));
        }
    }
    Ok(())
}

/// NAV_LOITER_TURNS: param 1 turns, param 3 the radius (positive: clockwise), around
/// `centre`, at height `z_m`.
fn orbit(
    w: &mut Writer,
    i: &MISSION_ITEM_INT_DATA,
    centre: Option<[f64; 2]>,
    z_m: f64,
) -> Result<(), Refusal> {
    let (turns, radius) = (f64::from(i.param1), f64::from(i.param3));
    if !(turns.is_finite() && radius.is_finite()) {
        return invalid(i, "turns (param 1) or radius (param 3) is not a number");
    }
    let Some([cx, cy]) = centre else {
        return invalid(i, "no centre (x, y)");
    };
    if (z_m - w.z_m).abs() > 1e-6 {
        // The orbit flies at the present height: climb (or descend) first, where the
        // vehicle will be.
        let Some(here) = w.xy_m else {
            return invalid(
                i,
                "a change of height with no known position before it: put a waypoint first",
            );
        };
        w.goto(i.seq, here, z_m);
    }
    let turn = if radius > 0.0 { "right" } else { "left" };
    let (r, speed) = (radius.abs(), w.speed_m_s);
    w.item(
        i.seq,
        format_args!(
            "kind = \"orbit\"\ncentre_m = [{cx:?}, {cy:?}]\nradius_m = {r:?}\n\
             speed_m_s = {speed:?}\nturns = {turns:?}\nturn = \"{turn}\"\n"
        ),
    );
    // Somewhere on the circle.
    w.xy_m = None;
    Ok(())
}

/// DO_CHANGE_SPEED: param 1 the speed's kind (0 air, 1 ground: both the path's speed here; 2
/// climb and 3 descent: the commander's own), param 2 the speed (−1: no change).
fn change_speed(w: &mut Writer, i: &MISSION_ITEM_INT_DATA) -> Result<(), Refusal> {
    let (kind, v) = (i.param1, f64::from(i.param2));
    if !(kind == 0.0 || kind == 1.0) || v == -1.0 {
        return Ok(());
    }
    if !(v.is_finite() && v > 0.0) {
        return invalid(
            i,
            "speed (param 2) must be above 0 m/s, or -1 for no change",
        );
    }
    w.speed_m_s = v;
    Ok(())
}

// Ground stations still send the *_INT frames the newest MAVLink folds into the others.
#[cfg(test)]
#[allow(deprecated)]
mod tests {
    use super::*;
    use crate::core::gps::offset_deg;

    const SITE: [f64; 2] = [-34.9, -56.2];

    fn item(
        seq: u16,
        command: MavCmd,
        frame: MavFrame,
        p: [f32; 4],
        x: i32,
        y: i32,
        z: f32,
    ) -> MISSION_ITEM_INT_DATA {
        MISSION_ITEM_INT_DATA {
            param1: p[0],
            param2: p[1],
            param3: p[2],
            param4: p[3],
            x,
            y,
            z,
            seq,
            command,
            frame,
            ..MISSION_ITEM_INT_DATA::DEFAULT
        }
    }

    fn global(
        seq: u16,
        command: MavCmd,
        p: [f32; 4],
        north_west_m: [f64; 2],
        z: f32,
    ) -> MISSION_ITEM_INT_DATA {
        let [lat, lon] = offset_deg(SITE, north_west_m);
        let e7 = |d: f64| (d * 1e7).round() as i32;
        item(
            seq,
            command,
            MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            p,
            e7(lat),
            e7(lon),
            z,
        )
    }

    fn anchor() -> Anchor {
        // The fix is 3 m north of the local origin, the takeoff point 1 m west of it.
        Anchor {
            fix_deg: Some(SITE),
            fix_xy_m: [3.0, 0.0],
            home_m: [0.0, 1.0, 0.5],
        }
    }

    fn parse(text: &str) -> toml::Value {
        toml::from_str(text).unwrap_or_else(|e| panic!("{e}\n{text}"))
    }

    #[test]
    fn before_the_estimate_local_heights_are_from_the_ground_whatever_the_fix_reads() {
        use crate::core::gps::{Fix, GpsSample, LiveFix};
        // The same 1 m takeoff sent while the receiver's altitude wanders by metres (it
        // became 1.0 to 5.65 m): the same height every time.
        let takeoff = item(
            0,
            MavCmd::MAV_CMD_NAV_TAKEOFF,
            MavFrame::MAV_FRAME_LOCAL_NED,
            [0.0; 4],
            0,
            0,
            -1.0,
        );
        let mut texts = Vec::new();
        for z_m in [0.0, 2.3, -1.7, 4.65] {
            let fix = LiveFix {
                seq: 1,
                fix: Fix {
                    mode: 3,
                    lat_deg: SITE[0],
                    lon_deg: SITE[1],
                    alt_m: Some(30.0 + z_m),
                    eph_m: Some(1.5),
                },
                sample: GpsSample::at([0.4, -0.2, z_m]),
                stamp_us: 0,
            };
            let a = Anchor::of(Some(&fix), None, None);
            assert_eq!(a.home_m, [0.4, -0.2, 0.0]);
            texts.push(
                convert(std::slice::from_ref(&takeoff), &a, 1.0, 1.0)
                    .unwrap()
                    .text,
            );
        }
        assert!(texts.iter().all(|t| *t == texts[0]), "{texts:?}");
        assert!(texts[0].contains("height_m = 1.0"), "{}", texts[0]);
        // With an estimate, or once a takeoff point exists, those anchor it.
        let est = Anchor::of(None, Some([1.0, 2.0, 0.3]), None);
        assert_eq!(est.home_m, [1.0, 2.0, 0.3]);
        let home = Anchor::of(None, Some([1.0, 2.0, 5.0]), Some([0.0, 0.0, 0.1]));
        assert_eq!(home.home_m, [0.0, 0.0, 0.1]);
    }

    #[test]
    fn offsets_invert_each_other() {
        let to = offset_deg(SITE, [12.5, -7.25]);
        let back = offset_m(SITE, to);
        assert!(
            (back[0] - 12.5).abs() < 1e-6 && (back[1] + 7.25).abs() < 1e-3,
            "{back:?}"
        );
    }

    #[test]
    fn an_upload_becomes_a_mission_file() {
        use MavCmd::*;
        let items = [
            item(
                0,
                MAV_CMD_NAV_TAKEOFF,
                MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                [0.0; 4],
                0,
                0,
                2.0,
            ),
            global(
                1,
                MAV_CMD_NAV_WAYPOINT,
                [3.0, 0.0, 0.0, 0.0],
                [10.0, 0.0],
                2.0,
            ),
            item(
                2,
                MAV_CMD_DO_CHANGE_SPEED,
                MavFrame::MAV_FRAME_MISSION,
                [1.0, 2.0, -1.0, 0.0],
                0,
                0,
                0.0,
            ),
            global(
                3,
                MAV_CMD_NAV_LOITER_TURNS,
                [1.5, 0.0, -4.0, 0.0],
                [10.0, -5.0],
                3.0,
            ),
            item(
                4,
                MAV_CMD_NAV_RETURN_TO_LAUNCH,
                MavFrame::MAV_FRAME_MISSION,
                [0.0; 4],
                0,
                0,
                0.0,
            ),
            item(
                5,
                MAV_CMD_NAV_LAND,
                MavFrame::MAV_FRAME_LOCAL_NED,
                [0.0; 4],
                10_000,
                20_000,
                0.0,
            ),
        ];
        let c = convert(&items, &anchor(), 1.0, 1.0).unwrap();
        // The waypoint's hold, the climb before the orbit and the landing's goto are items of
        // their own.
        assert_eq!(c.seq_of_item, [0, 1, 1, 3, 3, 4, 5, 5]);
        let v = parse(&c.text);
        let it = v["item"].as_array().unwrap();
        assert_eq!(it[0]["kind"].as_str(), Some("takeoff"));
        assert_eq!(it[0]["height_m"].as_float(), Some(2.0));
        // 10 m north of the fix, which is 3 m north of the origin; the takeoff point is 1 m
        // west of the origin.
        let at = it[1]["at_m"].as_array().unwrap();
        let at: Vec<f64> = at.iter().map(|v| v.as_float().unwrap()).collect();
        // Latitude and longitude in 1e-7 degrees: 1.1 cm steps.
        assert!(
            (at[0] - 13.0).abs() < 0.01 && (at[1] + 1.0).abs() < 0.01,
            "{at:?}"
        );
        assert_eq!(at[2], 2.0);
        assert_eq!(it[1]["speed_m_s"].as_float(), Some(1.0));
        assert_eq!(it[2]["seconds"].as_float(), Some(3.0));
        // Climb where the waypoint left the vehicle, then the orbit at the new speed.
        let climb = it[3]["at_m"].as_array().unwrap();
        assert_eq!(climb[2].as_float(), Some(3.0));
        assert_eq!(it[4]["kind"].as_str(), Some("orbit"));
        assert_eq!(it[4]["radius_m"].as_float(), Some(4.0));
        assert_eq!(it[4]["turn"].as_str(), Some("left"));
        assert_eq!(it[4]["speed_m_s"].as_float(), Some(2.0));
        assert_eq!(it[4]["turns"].as_float(), Some(1.5));
        assert_eq!(it[5]["kind"].as_str(), Some("return"));
        // LOCAL_NED: 1 m north, 2 m east = 2 m west negative.
        let land_at = it[6]["at_m"].as_array().unwrap();
        assert_eq!(land_at[0].as_float(), Some(1.0));
        // (the takeoff point is 1 m west of the local origin, LOCAL_NED's)
        assert_eq!(land_at[1].as_float(), Some(-3.0));
        assert_eq!(it[7]["kind"].as_str(), Some("land"));
    }

    #[test]
    fn what_cannot_be_flown_is_named() {
        use MavCmd::*;
        let no_fix = Anchor {
            fix_deg: None,
            ..anchor()
        };
        let wp = global(4, MAV_CMD_NAV_WAYPOINT, [0.0; 4], [5.0, 0.0], 2.0);
        let (r, why) = convert(&[wp], &no_fix, 1.0, 1.0).unwrap_err();
        assert_eq!(r, MavMissionResult::MAV_MISSION_DENIED);
        assert!(
            why.contains("item 4") && why.contains("no GPS fix"),
            "{why}"
        );
        let amsl = item(
            2,
            MAV_CMD_NAV_WAYPOINT,
            MavFrame::MAV_FRAME_GLOBAL_INT,
            [0.0; 4],
            1,
            1,
            50.0,
        );
        let (r, _) = convert(&[amsl], &anchor(), 1.0, 1.0).unwrap_err();
        assert_eq!(r, MavMissionResult::MAV_MISSION_UNSUPPORTED_FRAME);
        let spline = item(
            0,
            MAV_CMD_NAV_SPLINE_WAYPOINT,
            MavFrame::MAV_FRAME_MISSION,
            [0.0; 4],
            0,
            0,
            0.0,
        );
        let (r, why) = convert(&[spline], &anchor(), 1.0, 1.0).unwrap_err();
        assert_eq!(r, MavMissionResult::MAV_MISSION_UNSUPPORTED);
        assert!(why.contains("NAV_SPLINE_WAYPOINT"), "{why}");
        let stop = item(
            0,
            MAV_CMD_DO_CHANGE_SPEED,
            MavFrame::MAV_FRAME_MISSION,
            [1.0, 0.0, 0.0, 0.0],
            0,
            0,
            0.0,
        );
        let (r, _) = convert(&[stop], &anchor(), 1.0, 1.0).unwrap_err();
        assert_eq!(r, MavMissionResult::MAV_MISSION_INVALID);
        // −1 is "no change", and climb or descent speeds are not the path's.
        let mission = MavFrame::MAV_FRAME_MISSION;
        let keep = item(
            0,
            MAV_CMD_DO_CHANGE_SPEED,
            mission,
            [1.0, -1.0, 0.0, 0.0],
            0,
            0,
            0.0,
        );
        let climb = item(
            1,
            MAV_CMD_DO_CHANGE_SPEED,
            mission,
            [2.0, 3.0, 0.0, 0.0],
            0,
            0,
            0.0,
        );
        let wp = global(2, MAV_CMD_NAV_WAYPOINT, [0.0; 4], [5.0, 0.0], 2.0);
        let c = convert(&[keep, climb, wp], &anchor(), 1.5, 1.0).unwrap();
        assert!(c.text.contains("speed_m_s = 1.5"), "{}", c.text);
        // An orbit's change of height where the position is not known (no takeoff before).
        let orbit = global(
            0,
            MAV_CMD_NAV_LOITER_TURNS,
            [1.0, 0.0, 3.0, 0.0],
            [5.0, 0.0],
            3.0,
        );
        let (r, why) = convert(&[orbit], &anchor(), 1.0, 1.0).unwrap_err();
        assert_eq!(r, MavMissionResult::MAV_MISSION_INVALID);
        assert!(why.contains("no known position"), "{why}");
        // A height that is not a number, turns that are not a number: named, not written.
        let rel = MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT;
        let nan = item(0, MAV_CMD_NAV_TAKEOFF, rel, [0.0; 4], 0, 0, f32::NAN);
        let (_, why) = convert(&[nan], &anchor(), 1.0, 1.0).unwrap_err();
        assert!(why.contains("no height"), "{why}");
        let take = item(0, MAV_CMD_NAV_TAKEOFF, rel, [0.0; 4], 0, 0, 2.0);
        let spin = global(
            1,
            MAV_CMD_NAV_LOITER_TURNS,
            [f32::NAN, 0.0, 3.0, 0.0],
            [5.0, 0.0],
            2.0,
        );
        let (_, why) = convert(&[take, spin], &anchor(), 1.0, 1.0).unwrap_err();
        assert!(why.contains("not a number"), "{why}");
    }

    #[test]
    fn older_items_carry_degrees_as_floats() {
        let old = MISSION_ITEM_DATA {
            x: -34.9,
            y: -56.2,
            z: 2.0,
            seq: 3,
            frame: MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT,
            command: MavCmd::MAV_CMD_NAV_WAYPOINT,
            ..MISSION_ITEM_DATA::DEFAULT
        };
        let i = item_int(&old).unwrap();
        assert_eq!((i.seq, i.z), (3, 2.0));
        assert!((f64::from(i.x) / 1e7 + 34.9).abs() < 1e-5, "{}", i.x);
    }

    #[test]
    fn coordinates_that_are_not_numbers_are_refused_in_every_frame() {
        // As integers they read as 0: the local origin, acknowledged and flown.
        let nan = MISSION_ITEM_DATA {
            x: f32::NAN,
            y: f32::NAN,
            z: f32::NAN,
            seq: 1,
            frame: MavFrame::MAV_FRAME_LOCAL_NED,
            command: MavCmd::MAV_CMD_NAV_WAYPOINT,
            ..MISSION_ITEM_DATA::DEFAULT
        };
        let (r, why) = item_int(&nan).unwrap_err();
        assert_eq!(r, MavMissionResult::MAV_MISSION_INVALID_PARAM5_X, "{why}");
        assert!(why.contains("mission item 1: x is NaN"), "{why}");
        let inf_y = MISSION_ITEM_DATA {
            x: 1.0,
            y: f32::INFINITY,
            frame: MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT,
            ..nan
        };
        let (r, _) = item_int(&inf_y).unwrap_err();
        assert_eq!(r, MavMissionResult::MAV_MISSION_INVALID_PARAM6_Y);
        // An infinite height, in an integer item of any position frame (not a number is
        // MAVLink's "not given").
        for frame in [
            MavFrame::MAV_FRAME_LOCAL_NED,
            MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        ] {
            let mut take = item(0, MavCmd::MAV_CMD_NAV_TAKEOFF, frame, [0.0; 4], 0, 0, 2.0);
            take.z = f32::INFINITY;
            let (r, why) = convert(&[take], &anchor(), 1.0, 1.0).unwrap_err();
            assert_eq!(r, MavMissionResult::MAV_MISSION_INVALID_PARAM7, "{why}");
        }
    }
}
