//! GPS samples for the filter: gpsd's JSON reports, the fake-GPS generators of the 2012
//! flights, latitude/longitude to the local frame, and the schedule that applies a sample to
//! the next Kalman step.
//!
//! Spec sections 7.1 (gpsd client), 7.3 (lat/lon → UTM), 7.4 (fake GPS) with ERRATA 5 and 10. The local frame has
//! x north, y west, z up, in m, with its origin at the first fix (the original's absolute-UTM
//! state and its UTM integer-fraction bug are not reproduced).

/// A gpsd report (protocol 3): the classes the client handles; any other class is `Other`,
/// and unknown fields are ignored.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(tag = "class")]
pub enum Report {
    #[serde(rename = "TPV")]
    Tpv(Tpv),
    #[serde(rename = "SKY")]
    Sky(Sky),
    #[serde(rename = "VERSION")]
    Version(Version),
    #[serde(rename = "DEVICES")]
    Devices {},
    #[serde(rename = "WATCH")]
    Watch {},
    #[serde(rename = "ERROR")]
    Error {
        #[serde(default)]
        message: String,
    },
    #[serde(other)]
    Other,
}

/// Time-position-velocity report. gpsd leaves out what it does not know.
#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize)]
pub struct Tpv {
    /// 0 unknown, 1 no fix, 2 2D, 3 3D.
    #[serde(default)]
    pub mode: u8,
    pub time: Option<String>,
    pub lat: Option<f64>,
    pub lon: Option<f64>,
    /// Altitude above mean sea level (gpsd ≥ 3.20), m.
    #[serde(rename = "altMSL")]
    pub alt_msl: Option<f64>,
    /// Altitude (older gpsd; MSL), m.
    pub alt: Option<f64>,
    /// Height above the ellipsoid, m.
    #[serde(rename = "altHAE")]
    pub alt_hae: Option<f64>,
    pub epx: Option<f64>,
    pub epy: Option<f64>,
    pub epv: Option<f64>,
    /// Estimated horizontal position error (gpsd ≥ 3.20), m.
    pub eph: Option<f64>,
    /// Speed over ground, m/s; course over ground, degrees from true north clockwise; climb
    /// rate, m/s.
    pub speed: Option<f64>,
    pub track: Option<f64>,
    pub climb: Option<f64>,
}

/// Sky view: only the satellites' count is kept.
#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize)]
pub struct Sky {
    #[serde(default)]
    pub satellites: Vec<Satellite>,
}

#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize)]
pub struct Satellite {
    #[serde(rename = "PRN")]
    pub prn: Option<i64>,
    pub used: Option<bool>,
}

#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize)]
pub struct Version {
    #[serde(default)]
    pub release: String,
    #[serde(default)]
    pub proto_major: u32,
    #[serde(default)]
    pub proto_minor: u32,
}

/// A position fix from a TPV report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fix {
    /// 2 or 3.
    pub mode: u8,
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Altitude, m (MSL when gpsd gives it); none for a 2D fix without one.
    pub alt_m: Option<f64>,
    /// Horizontal error, m: gpsd's `eph`, else the larger of `epx` and `epy`; none when gpsd
    /// gives neither.
    pub eph_m: Option<f64>,
}

impl Tpv {
    /// The fix this report carries: mode 2 or 3 with finite latitude and longitude.
    pub fn fix(&self) -> Option<Fix> {
        if self.mode < 2 {
            return None;
        }
        let (lat, lon) = (self.lat?, self.lon?);
        if !(lat.is_finite() && lon.is_finite()) || lat.abs() > 90.0 || lon.abs() > 180.0 {
            return None;
        }
        let alt = self
            .alt_msl
            .or(self.alt)
            .or(self.alt_hae)
            .filter(|a| a.is_finite());
        let eph = self
            .eph
            .or_else(|| Some(self.epx?.max(self.epy?)))
            .filter(|e| e.is_finite() && *e >= 0.0);
        Some(Fix {
            mode: self.mode,
            lat_deg: lat,
            lon_deg: lon,
            alt_m: alt,
            eph_m: eph,
        })
    }
}

impl Tpv {
    /// The velocity in the local frame (north, west, up), m/s, when gpsd gives a finite speed
    /// and course. The climb is not a number when gpsd gives none or the fix is not 3D: read
    /// as 0 it would hold the vertical still where the barometer is lost (`core::ekf_fix`).
    pub fn velocity_m_s(&self) -> Option<[f64; 3]> {
        let (speed, track) = (self.speed?, self.track?);
        let climb = match self.climb {
            Some(c) if self.mode >= 3 => c,
            _ => f64::NAN,
        };
        if !(speed.is_finite() && track.is_finite()) {
            return None;
        }
        let (s, c) = track.to_radians().sin_cos();
        Some([speed * c, -speed * s, climb])
    }
}

/// Why a gpsd line was not understood.
#[derive(Debug, thiserror::Error)]
#[error("not a gpsd report: {0}")]
pub struct ReportError(#[from] serde_json::Error);

/// Parses one line of gpsd's JSON output.
pub fn parse_report(line: &str) -> Result<Report, ReportError> {
    Ok(serde_json::from_str(line)?)
}

/// A fix as it reaches the estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiveFix {
    /// Increases with every fix.
    pub seq: u64,
    pub fix: Fix,
    pub sample: GpsSample,
    /// Arrival, µs since the run's start.
    pub stamp_us: i64,
}

/// One GPS sample for the filter: position in the local frame, m. A fix without altitude (2D)
/// has no z: the filter then keeps the barometer's altitude row instead of inventing one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpsSample {
    pub xy_m: [f64; 2],
    pub z_m: Option<f64>,
    /// The receiver's velocity in the local frame (north, west, up), m/s, when it gives one.
    pub vel_m_s: Option<[f64; 3]>,
}

impl GpsSample {
    /// A sample with all three coordinates.
    pub fn at(pos_m: [f64; 3]) -> Self {
        GpsSample {
            xy_m: [pos_m[0], pos_m[1]],
            z_m: Some(pos_m[2]),
            vel_m_s: None,
        }
    }

    /// x, y, z with z not a number when unknown (the gps.log column).
    pub fn pos_m(&self) -> [f64; 3] {
        [self.xy_m[0], self.xy_m[1], self.z_m.unwrap_or(f64::NAN)]
    }
}

/// Small deterministic generator (SplitMix64) for the seeded fake-random GPS mode: the same
/// seed gives the same positions on every machine.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Positions of fake samples: all zero (the 2012 flights) or seeded noise around zero
/// (`GPS_RAND`: x, y ∈ U[−½, ½)·span, z ∈ U[−1, 1)·span).
#[derive(Debug, Clone)]
pub enum FakePositions {
    Zero,
    Random { rng: SplitMix64, span_m: f64 },
}

impl FakePositions {
    pub fn next_sample(&mut self) -> GpsSample {
        match self {
            FakePositions::Zero => GpsSample::at([0.0; 3]),
            FakePositions::Random { rng, span_m } => {
                let x = (rng.next_f64() - 0.5) * *span_m;
                let y = (rng.next_f64() - 0.5) * *span_m;
                let z = (rng.next_f64() * 2.0 - 1.0) * *span_m;
                GpsSample::at([x, y, z])
            }
        }
    }
}

/// The original's fake-GPS timing (ERRATA 10): a check once per control cycle, right after the
/// motor command. The first command yields a sample; each later sample comes with the first
/// command at least 1 s after the command that produced the previous one.
#[derive(Debug, Clone, Default)]
pub struct FakeGpsClock {
    last_sample_cmd_us: Option<i64>,
}

/// Period of the fake samples, µs.
pub const FAKE_GPS_PERIOD_US: i64 = 1_000_000;

impl FakeGpsClock {
    /// Called after each motor command at `t_cmd_us`; `true` when a sample is due now.
    pub fn on_motor_command(&mut self, t_cmd_us: i64) -> bool {
        let due = match self.last_sample_cmd_us {
            None => true,
            Some(last) => t_cmd_us - last >= FAKE_GPS_PERIOD_US,
        };
        if due {
            self.last_sample_cmd_us = Some(t_cmd_us);
        }
        due
    }
}

/// Recorded samples applied by time (ERRATA 5): a sample stamped t is fused by the first
/// Kalman step whose time is later than t.
#[derive(Debug, Clone, Default)]
pub struct RecordedGps {
    samples: Vec<(i64, GpsSample)>,
    next: usize,
}

impl RecordedGps {
    /// `samples` must be in time order (as a log is).
    pub fn new(samples: Vec<(i64, GpsSample)>) -> Self {
        RecordedGps { samples, next: 0 }
    }

    /// The newest sample stamped before `t_step_us` not yet used, if any. Older pending
    /// samples are superseded (a step fuses one position).
    pub fn take_before(&mut self, t_step_us: i64) -> Option<GpsSample> {
        let mut out = None;
        while let Some(&(t, s)) = self.samples.get(self.next) {
            if t >= t_step_us {
                break;
            }
            out = Some(s);
            self.next += 1;
        }
        out
    }
}

/// UTM coordinates on WGS84 (spec 7.3, after deg2utm.m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Utm {
    pub easting_m: f64,
    pub northing_m: f64,
    pub zone: i32,
}

/// Mean Earth radius, m: offsets of metres from a known point need no projection.
const EARTH_RADIUS_M: f64 = 6_371_000.0;

/// The latitude and longitude `offset_m` (north, west; m, the local frame's axes) away from
/// `from_deg` (latitude, longitude), degrees. On a sphere: within 0.3 % of the ellipsoid's
/// answer, centimetres over the tens of metres a vehicle strays from a fix.
pub fn offset_deg(from_deg: [f64; 2], offset_m: [f64; 2]) -> [f64; 2] {
    let [lat, lon] = from_deg;
    let dlat_rad = offset_m[0] / EARTH_RADIUS_M;
    let dlon_rad = -offset_m[1] / (EARTH_RADIUS_M * lat.to_radians().cos());
    [lat + dlat_rad.to_degrees(), lon + dlon_rad.to_degrees()]
}

/// The offset (north, west; m) from `from_deg` to `to_deg` (latitude, longitude): the inverse
/// of [`offset_deg`].
pub fn offset_m(from_deg: [f64; 2], to_deg: [f64; 2]) -> [f64; 2] {
    let dlat_rad = (to_deg[0] - from_deg[0]).to_radians();
    let dlon_rad = (to_deg[1] - from_deg[1]).to_radians();
    [
        dlat_rad * EARTH_RADIUS_M,
        -dlon_rad * EARTH_RADIUS_M * from_deg[0].to_radians().cos(),
    ]
}

/// Latitude/longitude (degrees) to UTM, with the fractions 3/4, 5/3 and 35/27 evaluated as
/// real numbers (the gpsd-era copy of the original truncated them to integers).
pub fn deg_to_utm(lat_deg: f64, lon_deg: f64) -> Utm {
    deg_to_utm_in_zone(lat_deg, lon_deg, utm_zone(lon_deg))
}

/// The UTM zone of a longitude, degrees.
pub fn utm_zone(lon_deg: f64) -> i32 {
    (lon_deg / 6.0 + 31.0).floor() as i32
}

/// [`deg_to_utm`] projected in a given zone (its central meridian), so that positions on both
/// sides of a zone boundary stay in one plane.
pub fn deg_to_utm_in_zone(lat_deg: f64, lon_deg: f64, zone: i32) -> Utm {
    let ee = 0.006_739_496_742_333_46;
    let c = 6_399_593.625_758_67;
    let lat = lat_deg.to_radians();
    let lon = lon_deg.to_radians();
    // In f64: for a longitude far outside ±180° (an unchecked log) the zone saturates, and
    // 6·zone would overflow an i32.
    let s = 6.0 * f64::from(zone) - 183.0;
    let d_lambda = lon - s.to_radians();
    let cos_lat = lat.cos();
    let a = cos_lat * d_lambda.sin();
    let epsilon = 0.5 * ((1.0 + a) / (1.0 - a)).ln();
    let nu = (lat.tan() / d_lambda.cos()).atan() - lat;
    let v = 0.9996 * c / (1.0 + ee * cos_lat * cos_lat).sqrt();
    let ta = ee / 2.0 * epsilon * epsilon * cos_lat * cos_lat;
    let a1 = (2.0 * lat).sin();
    let a2 = a1 * cos_lat * cos_lat;
    let j2 = lat + a1 / 2.0;
    let j4 = (3.0 * j2 + a2) / 4.0;
    let j6 = (5.0 * j4 + a2 * cos_lat * cos_lat) / 3.0;
    let alpha = 0.75 * ee;
    let beta = 5.0 / 3.0 * alpha * alpha;
    let gamma = 35.0 / 27.0 * alpha * alpha * alpha;
    let bm = 0.9996 * c * (lat - alpha * j2 + beta * j4 - gamma * j6);
    let easting_m = epsilon * v * (1.0 + ta / 3.0) + 500_000.0;
    let mut northing_m = nu * v * (1.0 + ta) + bm;
    if northing_m < 0.0 {
        northing_m += 9_999_999.0;
    }
    Utm {
        easting_m,
        northing_m,
        zone,
    }
}

/// The local frame (x north, y west, z up) anchored at the first fix it sees, projected in
/// that fix's UTM zone for the whole run (a fix across a zone boundary would otherwise jump by
/// hundreds of km); its altitude origin is the first fix that has an altitude.
#[derive(Debug, Clone, Default)]
pub struct LocalFrame {
    origin: Option<Utm>,
    alt_origin_m: Option<f64>,
}

impl LocalFrame {
    /// Position of a fix in the local frame, m; no z for a fix without altitude.
    pub fn to_local(&mut self, lat_deg: f64, lon_deg: f64, alt_m: Option<f64>) -> GpsSample {
        let zone = self.origin.map_or_else(|| utm_zone(lon_deg), |o| o.zone);
        let utm = deg_to_utm_in_zone(lat_deg, lon_deg, zone);
        let o = *self.origin.get_or_insert(utm);
        // An altitude that is not a number is no altitude.
        let z_m = alt_m
            .filter(|a| a.is_finite())
            .map(|a| a - *self.alt_origin_m.get_or_insert(a));
        GpsSample {
            xy_m: [
                utm.northing_m - o.northing_m,
                -(utm.easting_m - o.easting_m),
            ],
            z_m,
            vel_m_s: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // Lines gpsd 3.22 wrote for an NMEA stream (RMC + GGA + GSA) of this project's tests.
    const TPV_3D: &str = r#"{"class":"TPV","device":"tcp://127.0.0.1:29471","mode":3,"time":"2031-09-15T12:00:04.000Z","ept":0.005,"lat":-34.919588333,"lon":-56.166258333,"altHAE":41.7000,"altMSL":27.7000,"alt":27.7000,"epv":27.600,"track":0.0000,"magtrack":349.0664,"magvar":-10.9,"speed":0.000,"climb":0.000,"epc":55.20,"geoidSep":14.000,"eph":1.800,"sep":3.000}"#;
    const VERSION: &str =
        r#"{"class":"VERSION","release":"3.22","rev":"3.22","proto_major":3,"proto_minor":14}"#;
    const DEVICES: &str = r#"{"class":"DEVICES","devices":[{"class":"DEVICE","path":"tcp://127.0.0.1:29471","driver":"NMEA0183","activated":"2026-11-22T19:21:31.304Z","flags":1}]}"#;
    const WATCH: &str = r#"{"class":"WATCH","enable":true,"json":true,"nmea":false,"raw":0,"scaled":false,"timing":false,"split24":false,"pps":false}"#;

    #[test]
    fn gpsd_velocity_is_turned_into_the_local_frame() {
        let tpv = |speed: f64, track: f64, climb: Option<f64>| Tpv {
            mode: 3,
            speed: Some(speed),
            track: Some(track),
            climb,
            ..Tpv::default()
        };
        // East at 2 m/s is −y (west up); north-west at √2 m/s is +x, +y.
        let v = tpv(2.0, 90.0, Some(0.5)).velocity_m_s().unwrap();
        assert!(v[0].abs() < 1e-12 && (v[1] + 2.0).abs() < 1e-12 && v[2] == 0.5);
        let v = tpv(2f64.sqrt(), 315.0, None).velocity_m_s().unwrap();
        assert!((v[0] - 1.0).abs() < 1e-12 && (v[1] - 1.0).abs() < 1e-12 && v[2].is_nan());
        let two_d = Tpv {
            mode: 2,
            ..tpv(1.0, 0.0, Some(0.5))
        };
        assert!(
            two_d.velocity_m_s().is_some_and(|v| v[2].is_nan()),
            "no climb in 2D"
        );
        assert_eq!(tpv(f64::NAN, 0.0, None).velocity_m_s(), None);
        let Report::Tpv(t) = parse_report(TPV_3D).unwrap() else {
            panic!()
        };
        assert_eq!(t.velocity_m_s(), Some([0.0, -0.0, 0.0]));
    }

    #[test]
    fn parses_the_report_classes() {
        let Report::Tpv(t) = parse_report(TPV_3D).unwrap() else {
            panic!()
        };
        let f = t.fix().unwrap();
        assert_eq!(f.mode, 3);
        assert_eq!(
            (f.lat_deg, f.lon_deg, f.alt_m),
            (-34.919588333, -56.166258333, Some(27.7))
        );
        assert_eq!(
            parse_report(VERSION).unwrap(),
            Report::Version(Version {
                release: "3.22".into(),
                proto_major: 3,
                proto_minor: 14
            })
        );
        assert_eq!(parse_report(DEVICES).unwrap(), Report::Devices {});
        assert_eq!(parse_report(WATCH).unwrap(), Report::Watch {});
        assert!(matches!(
            parse_report(r#"{"class":"SKY","satellites":[{"PRN":1},{"PRN":2}]}"#).unwrap(),
            Report::Sky(s) if s.satellites.len() == 2
        ));
        assert_eq!(
            parse_report(r#"{"class":"ERROR","message":"unrecognized request"}"#).unwrap(),
            Report::Error {
                message: "unrecognized request".into()
            }
        );
        assert_eq!(
            parse_report(r#"{"class":"PPS","x":1}"#).unwrap(),
            Report::Other
        );
        assert!(parse_report("not json").is_err());
        assert!(parse_report(r#"{"no":"class"}"#).is_err());
    }

    #[test]
    fn no_fix_and_missing_fields() {
        let no_fix =
            r#"{"class":"TPV","device":"/dev/ttyUSB0","mode":1,"time":"2012-01-30T23:03:06.000Z"}"#;
        let Report::Tpv(t) = parse_report(no_fix).unwrap() else {
            panic!()
        };
        assert_eq!(t.fix(), None);
        // Mode 3 claimed but no longitude: not a fix.
        let Report::Tpv(t) = parse_report(r#"{"class":"TPV","mode":3,"lat":-34.9}"#).unwrap()
        else {
            panic!()
        };
        assert_eq!(t.fix(), None);
        // 2D fix without altitude: none (not 0 m); older gpsd's "alt" is used when altMSL is
        // absent.
        let Report::Tpv(t) =
            parse_report(r#"{"class":"TPV","mode":2,"lat":-34.9,"lon":-56.1}"#).unwrap()
        else {
            panic!()
        };
        assert_eq!(t.fix().unwrap().alt_m, None);
        let Report::Tpv(t) =
            parse_report(r#"{"class":"TPV","mode":3,"lat":-34.9,"lon":-56.1,"alt":12.5}"#).unwrap()
        else {
            panic!()
        };
        assert_eq!(t.fix().unwrap().alt_m, Some(12.5));
        // No mode at all.
        let Report::Tpv(t) = parse_report(r#"{"class":"TPV"}"#).unwrap() else {
            panic!()
        };
        assert_eq!(t.mode, 0);
        assert_eq!(t.fix(), None);
    }

    #[test]
    fn utm_matches_an_independent_projection() {
        // Reference: PROJ (pyproj, WGS84, UTM zone 21 south) gives easting 576155.59369 m and
        // northing 6135557.03531 m for this 2012 fix; deg2utm's series is within 2 cm and uses
        // a false northing of 9 999 999 m instead of 10 000 000 m.
        let u = deg_to_utm(-34.919588333, -56.166258333);
        assert_eq!(u.zone, 21);
        assert!((u.easting_m - 576_155.593_69).abs() < 1e-3, "{u:?}");
        assert!(
            (u.northing_m + 1.0 - 6_135_557.035_31).abs() < 0.02,
            "{u:?}"
        );
    }

    #[test]
    fn any_coordinates_convert_without_a_panic() {
        // An original gps.log is replayed from its unchecked latitude and longitude; a
        // longitude beyond about ±2.1e9° once overflowed the zone's central meridian (i32).
        for (lat, lon) in [
            (0.0, -9.26e234),
            (0.0, 1e12),
            (f64::MAX, f64::MIN),
            (f64::NAN, f64::INFINITY),
            (90.0, 180.0),
        ] {
            let _ = deg_to_utm(lat, lon);
            let _ = LocalFrame::default().to_local(lat, lon, Some(f64::NAN));
        }
        assert_eq!(deg_to_utm(0.0, 1e12).zone, i32::MAX);
    }

    #[test]
    fn offsets_in_degrees_agree_with_the_local_frame() {
        let from = [-34.919588333, -56.166258333];
        let to = offset_deg(from, [10.0, -20.0]);
        let mut frame = LocalFrame::default();
        frame.to_local(from[0], from[1], None);
        let s = frame.to_local(to[0], to[1], None);
        // 10 m north and 20 m east: the local frame is the UTM grid's, turned from true north
        // by the grid convergence here (zone 21's meridian is 57° W: about −0.48°, 0.17 m
        // over these 20 m). The sphere's offsets are within 0.3 % of the ellipsoid's.
        let convergence = (from[1] + 57.0).to_radians() * from[0].to_radians().sin();
        let north = 10.0 * convergence.cos() + 20.0 * convergence.sin();
        let west = -20.0 * convergence.cos() + 10.0 * convergence.sin();
        assert!((s.xy_m[0] - north).abs() < 0.06, "{s:?} {north}");
        assert!((s.xy_m[1] - west).abs() < 0.06, "{s:?} {west}");
    }

    #[test]
    fn local_frame_is_north_west_up() {
        // Offsets from PROJ for the same points: 0.001° north moves +110.8985 m in northing and
        // +0.9303 m in easting (grid convergence); 0.001° east moves +91.3660 m in easting.
        let mut f = LocalFrame::default();
        assert_eq!(
            f.to_local(-34.9, -56.16, Some(30.0)),
            GpsSample::at([0.0, 0.0, 0.0])
        );
        let p = f.to_local(-34.899, -56.16, Some(31.0)).pos_m();
        assert!((p[0] - 110.8985).abs() < 0.01, "{p:?}");
        assert!((p[1] + 0.9303).abs() < 0.01, "{p:?}");
        assert_eq!(p[2], 1.0);
        let p = f.to_local(-34.9, -56.159, Some(30.0)).pos_m();
        assert!((p[1] + 91.3660).abs() < 0.01, "{p:?}");
    }

    #[test]
    fn a_fix_without_altitude_has_no_z_and_does_not_set_the_altitude_origin() {
        let mut f = LocalFrame::default();
        assert_eq!(f.to_local(-34.9, -56.16, None).z_m, None);
        assert_eq!(f.to_local(-34.9, -56.16, Some(30.0)).z_m, Some(0.0));
        assert_eq!(f.to_local(-34.9, -56.16, Some(31.5)).z_m, Some(1.5));
    }

    #[test]
    fn the_utm_zone_stays_the_origins_across_a_boundary() {
        // 54° W is the boundary of zones 21 and 22: 0.001° east of it is 91 m east, not the
        // hundreds of km a projection in zone 22 would put it.
        let mut f = LocalFrame::default();
        f.to_local(-34.9, -54.0005, Some(30.0));
        let p = f.to_local(-34.9, -53.9995, Some(30.0)).pos_m();
        assert_eq!(utm_zone(-53.9995), 22);
        assert!((p[1] + 91.37).abs() < 0.05, "{p:?}");
        assert!(p[0].abs() < 5.0, "{p:?}");
    }

    #[test]
    fn fake_clock_follows_errata_10() {
        let mut c = FakeGpsClock::default();
        assert!(c.on_motor_command(12_134_736));
        assert!(!c.on_motor_command(12_145_295));
        assert!(!c.on_motor_command(13_134_000));
        assert!(c.on_motor_command(13_134_736));
        assert!(!c.on_motor_command(14_134_735));
        assert!(c.on_motor_command(14_140_000));
    }

    #[test]
    fn recorded_samples_apply_to_the_next_step() {
        let s = GpsSample::at([1.0, 2.0, 3.0]);
        let mut r = RecordedGps::new(vec![(100, s), (250, s)]);
        assert_eq!(r.take_before(100), None);
        assert_eq!(r.take_before(101), Some(s));
        assert_eq!(r.take_before(200), None);
        assert_eq!(r.take_before(300), Some(s));
        assert_eq!(r.take_before(400), None);
    }

    #[test]
    fn random_positions_are_seeded_and_bounded() {
        let mk = || FakePositions::Random {
            rng: SplitMix64::new(7),
            span_m: 1.0,
        };
        let (mut a, mut b) = (mk(), mk());
        for _ in 0..1000 {
            let (p, q) = (a.next_sample(), b.next_sample());
            assert_eq!(p, q);
            let p = p.pos_m();
            assert!(p[0].abs() <= 0.5 && p[1].abs() <= 0.5 && p[2].abs() <= 1.0);
        }
    }
}
