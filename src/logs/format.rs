//! Record types, parsers and printers of the original's log files.

use crate::core::ekf::{GatedGroups, TestRatios};
use crate::core::imu::calib::ImuSample;
use crate::core::imu::frame::RawFrame;
use std::fmt::Write as _;

pub use super::numbers::{push_fixed, push_shortest_exp, push_time_us, push_u64};

/// A log line that could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct LineError {
    /// 1-based line number in the file.
    pub line: usize,
    pub message: String,
}

/// Splits a log's text into (1-based line number, trimmed record), accepting `\n`, `\r\n` and
/// `\n\r` and skipping blank or whitespace-only pieces and `#` comment lines.
pub fn records(text: &str) -> impl Iterator<Item = (usize, &str)> {
    Records {
        text,
        pos: 0,
        line: 0,
    }
}

/// [`records`]' iterator: finds each line's end eight bytes at a time (logs are read whole and
/// split into a few thousand lines, once per replay).
struct Records<'a> {
    text: &'a str,
    /// Where the next line starts; past the end when done.
    pos: usize,
    /// The line number of the last line returned.
    line: usize,
}

impl<'a> Iterator for Records<'a> {
    type Item = (usize, &'a str);

    fn next(&mut self) -> Option<(usize, &'a str)> {
        while self.pos <= self.text.len() {
            let start = self.pos;
            let end = find_newline(self.text.as_bytes(), start);
            self.pos = end + 1;
            self.line += 1;
            // `\n` is ASCII, so both ends are character boundaries.
            let body = trim_record(&self.text[start..end]);
            if !body.is_empty() && !body.starts_with('#') {
                return Some((self.line, body));
            }
        }
        None
    }
}

/// The index of the first `\n` in `bytes` at or after `from`, or `bytes.len()`.
fn find_newline(bytes: &[u8], from: usize) -> usize {
    const ONES: u64 = 0x0101_0101_0101_0101;
    const HIGHS: u64 = 0x8080_8080_8080_8080;
    let mut i = from;
    while let Some(word) = bytes.get(i..i + 8) {
        let mut eight = [0u8; 8];
        eight.copy_from_slice(word);
        let x = u64::from_le_bytes(eight) ^ (ONES * u64::from(b'\n'));
        // The lowest byte that is zero in x sets its high bit here (higher ones may be false).
        let zero = x.wrapping_sub(ONES) & !x & HIGHS;
        if zero != 0 {
            return i + zero.trailing_zeros() as usize / 8;
        }
        i += 8;
    }
    bytes[i.min(bytes.len())..]
        .iter()
        .position(|&b| b == b'\n')
        .map_or(bytes.len(), |k| i + k)
}

/// A line without its surrounding whitespace (a `\r` of any line end included); checked on
/// the bytes first, since a log's lines almost always start and end in a printable character.
fn trim_record(line: &str) -> &str {
    let printable = |b: &u8| b.is_ascii_graphic();
    let bytes = line.as_bytes();
    if bytes.first().is_some_and(printable) && bytes.last().is_some_and(printable) {
        return line;
    }
    line.trim_matches(|c: char| c == '\r' || c.is_whitespace())
}

/// Formats a time in µs as the original's `%ld.%06ld` seconds.
pub fn fmt_time_us(t_us: i64) -> String {
    let mut s = String::new();
    push_time_us(&mut s, t_us);
    s
}

/// Parses a `seconds.micros` time exactly into µs (digits past the sixth are rounded).
pub fn parse_time_us(s: &str) -> Option<i64> {
    let bytes = s.as_bytes();
    let (neg, body) = match bytes.split_first() {
        Some((b'-', rest)) => (true, rest),
        _ => (false, bytes),
    };
    // One pass over the seconds' digits, up to the point.
    let mut secs: i64 = 0;
    let mut i = 0;
    while let Some(&c) = body.get(i).filter(|&&c| c != b'.') {
        secs = secs.checked_mul(10)?.checked_add(digit(c)?)?;
        i += 1;
    }
    let whole_digits = i;
    let frac = body.get(i + 1..).unwrap_or(&[]);
    if whole_digits == 0 && frac.is_empty() {
        return None;
    }
    let mut micros: i64 = 0;
    for k in 0..6 {
        micros = micros * 10 + frac.get(k).map_or(Some(0), |&c| digit(c))?;
    }
    match frac.get(6..) {
        Some(rest) if !rest.iter().all(u8::is_ascii_digit) => return None,
        Some([round, ..]) if *round >= b'5' => micros += 1,
        _ => {}
    }
    let t = secs.checked_mul(1_000_000)?.checked_add(micros)?;
    Some(if neg { -t } else { t })
}

/// The value of an ASCII decimal digit.
fn digit(c: u8) -> Option<i64> {
    c.is_ascii_digit().then(|| i64::from(c - b'0'))
}

fn field<T: std::str::FromStr>(fields: &[&str], i: usize, what: &str) -> Result<T, String> {
    let text = fields
        .get(i)
        .ok_or_else(|| format!("missing column {} ({what})", i + 1))?;
    text.parse()
        .map_err(|_| format!("column {} ({what}) is malformed: {text:?}", i + 1))
}

fn time_field(fields: &[&str], i: usize, what: &str) -> Result<i64, String> {
    let text = fields
        .get(i)
        .ok_or_else(|| format!("missing column {} ({what})", i + 1))?;
    parse_time_us(text).ok_or_else(|| format!("column {} ({what}) is not a time: {text:?}", i + 1))
}

/// Parses every record of a log with `parse`, naming the line of the first bad record. A bad
/// **last** record is dropped and reported in `truncated` instead: the original's logs can end
/// in a partly written line when a run is cut off.
pub fn parse_log<T>(
    text: &str,
    parse: impl Fn(&[&str]) -> Result<T, String>,
) -> Result<Parsed<T>, LineError> {
    parse_log_columns(text, usize::MAX, parse)
}

/// [`parse_log`] handing `parse` only each record's first `columns` columns (a reader of a
/// log's times need not split the rest of each line).
pub fn parse_log_columns<T>(
    text: &str,
    columns: usize,
    parse: impl Fn(&[&str]) -> Result<T, String>,
) -> Result<Parsed<T>, LineError> {
    // Room for a row per line of a log's usual length (60 bytes or more).
    let mut rows = Vec::with_capacity(text.len() / 60 + 1);
    let mut truncated = None;
    let mut fields: Vec<&str> = Vec::with_capacity(16);
    let mut lines = records(text).peekable();
    while let Some((line, body)) = lines.next() {
        fields.clear();
        fields.extend(body.split_ascii_whitespace().take(columns));
        match parse(&fields) {
            Ok(r) => rows.push(r),
            Err(message) if lines.peek().is_none() && !rows.is_empty() => {
                truncated = Some(LineError { line, message })
            }
            Err(message) => return Err(LineError { line, message }),
        }
    }
    Ok(Parsed { rows, truncated })
}

/// The rows of a log, and the dropped last line if it was cut off.
#[derive(Debug, Clone, PartialEq)]
pub struct Parsed<T> {
    pub rows: Vec<T>,
    pub truncated: Option<LineError>,
}

/// One `imu_raw.log` line (spec 1.6).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuRawRecord {
    /// Time since the program started when the frame was used, µs.
    pub t_main_us: i64,
    /// Frame stamp (the original: absolute wall clock), µs.
    pub t_frame_us: i64,
    pub frame: RawFrame,
}

impl ImuRawRecord {
    pub fn parse_fields(f: &[&str]) -> Result<Self, String> {
        if f.len() != 14 {
            return Err(format!("expected 14 columns, found {}", f.len()));
        }
        let i16_at = |i: usize, what: &str| field::<i16>(f, i, what);
        // The original printed the temperature as unsigned; read either form.
        let temp_dc = match f[12].parse::<i16>() {
            Ok(v) => v,
            Err(_) => field::<u16>(f, 12, "temp")? as i16,
        };
        Ok(ImuRawRecord {
            t_main_us: time_field(f, 0, "t_main")?,
            t_frame_us: time_field(f, 1, "t_frame")?,
            frame: RawFrame {
                t_us: field(f, 2, "T_us")?,
                acc: [
                    i16_at(3, "acc x")?,
                    i16_at(4, "acc y")?,
                    i16_at(5, "acc z")?,
                ],
                gyro: [
                    i16_at(6, "gyro x")?,
                    i16_at(7, "gyro y")?,
                    i16_at(8, "gyro z")?,
                ],
                magn: [
                    i16_at(9, "magn x")?,
                    i16_at(10, "magn y")?,
                    i16_at(11, "magn z")?,
                ],
                temp_dc,
                pres_pa: field(f, 13, "pressure")?,
            },
        })
    }

    pub fn write(&self, out: &mut String) {
        push_time_us(out, self.t_main_us);
        out.push('\t');
        push_time_us(out, self.t_frame_us);
        let f = &self.frame;
        let _ = write!(out, "\t{}", f.t_us);
        for v in f.acc.iter().chain(&f.gyro).chain(&f.magn) {
            let _ = write!(out, "\t{v}");
        }
        // Printed unsigned, as the original did.
        let _ = writeln!(out, "\t{}\t{}", f.temp_dc as u16, f.pres_pa);
    }
}

/// One `kalman_in.log` line: the filter's measurement input (spec 8.6).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KalmanInRecord {
    /// Time of the Kalman step, µs since start.
    pub t_us: i64,
    /// Time since the previous used IMU sample, µs (not the filter's dt).
    pub dt_us: i64,
    /// The T_us column (the 2012 logs hold 0 there).
    pub t_frame_col: f64,
    pub acc_m_s2: [f64; 3],
    pub gyro_rad_s: [f64; 3],
    /// ψ, φ, θ (θ unwrapped), rad.
    pub euler_rad: [f64; 3],
    pub temp_c: f64,
    pub alt_m: f64,
}

impl KalmanInRecord {
    pub fn from_sample(t_us: i64, dt_us: i64, s: &ImuSample) -> Self {
        KalmanInRecord {
            t_us,
            dt_us,
            // The original's logs carry 0 in this column; keep it.
            t_frame_col: 0.0,
            acc_m_s2: s.acc_m_s2,
            gyro_rad_s: s.gyro_rad_s,
            euler_rad: s.euler_rad,
            temp_c: s.temp_c,
            alt_m: s.alt_m,
        }
    }

    /// The 11 measurement columns (4–14), in file order.
    pub fn measurements(&self) -> [f64; 11] {
        let (a, g, e) = (self.acc_m_s2, self.gyro_rad_s, self.euler_rad);
        [
            a[0],
            a[1],
            a[2],
            g[0],
            g[1],
            g[2],
            e[0],
            e[1],
            e[2],
            self.temp_c,
            self.alt_m,
        ]
    }

    pub fn parse_fields(f: &[&str]) -> Result<Self, String> {
        if f.len() != 14 {
            return Err(format!("expected 14 columns, found {}", f.len()));
        }
        let mut v = [0.0; 11];
        for (k, slot) in v.iter_mut().enumerate() {
            *slot = field(f, 3 + k, "measurement")?;
        }
        Ok(KalmanInRecord {
            t_us: time_field(f, 0, "t_kalman")?,
            dt_us: time_field(f, 1, "dt")?,
            t_frame_col: field(f, 2, "T_us")?,
            acc_m_s2: [v[0], v[1], v[2]],
            gyro_rad_s: [v[3], v[4], v[5]],
            euler_rad: [v[6], v[7], v[8]],
            temp_c: v[9],
            alt_m: v[10],
        })
    }

    pub fn write(&self, out: &mut String) {
        push_time_us(out, self.t_us);
        out.push('\t');
        push_time_us(out, self.dt_us);
        out.push('\t');
        push_fixed(out, self.t_frame_col, 8);
        for v in self.measurements() {
            out.push('\t');
            push_fixed(out, v, 8);
        }
        out.push('\n');
    }
}

/// One `innov.log` line (uquad's own stream; the original had none): a Kalman step's time,
/// its attitude, altitude and gps innovation test ratios, and the groups it left out of its
/// update as one number, so that the file loads as a matrix as the original's logs do:
/// 1 attitude + 2 altitude + 4 gps, 0 when every group was fused. A ratio prints in the
/// shortest form that reads back to the same f64 (ratios span many decades: fixed decimals
/// would print most of them as 0); `nan` for a step without GPS or a measurement that was not
/// a number.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InnovRecord {
    /// Time of the Kalman step, µs since start.
    pub t_us: i64,
    pub ratios: TestRatios,
    pub gated: GatedGroups,
}

impl InnovRecord {
    /// The gated column's bits.
    const ATTITUDE: u8 = 1;
    const ALTITUDE: u8 = 2;
    const GPS: u8 = 4;

    pub fn gated_mask(g: GatedGroups) -> u8 {
        u8::from(g.attitude) * Self::ATTITUDE
            + u8::from(g.altitude) * Self::ALTITUDE
            + u8::from(g.gps) * Self::GPS
    }

    pub fn write(&self, out: &mut String) {
        push_time_us(out, self.t_us);
        let r = &self.ratios;
        for v in [r.attitude, r.altitude, r.gps.unwrap_or(f64::NAN)] {
            out.push('\t');
            push_ratio(out, v);
        }
        out.push('\t');
        push_u64(out, u64::from(Self::gated_mask(self.gated)));
        out.push('\n');
    }

    pub fn parse_fields(f: &[&str]) -> Result<Self, String> {
        if f.len() != 5 {
            return Err(format!("expected 5 columns, found {}", f.len()));
        }
        let gps: f64 = field(f, 3, "gps ratio")?;
        let mask: u8 = field(f, 4, "gated")?;
        if mask > Self::ATTITUDE + Self::ALTITUDE + Self::GPS {
            return Err(format!("column 5 (gated) is not a group mask: {mask}"));
        }
        Ok(InnovRecord {
            t_us: time_field(f, 0, "time")?,
            ratios: TestRatios {
                attitude: field(f, 1, "attitude ratio")?,
                altitude: field(f, 2, "altitude ratio")?,
                gps: (!gps.is_nan()).then_some(gps),
            },
            gated: GatedGroups {
                attitude: mask & Self::ATTITUDE != 0,
                altitude: mask & Self::ALTITUDE != 0,
                gps: mask & Self::GPS != 0,
            },
        })
    }
}

/// A test ratio, shortest round-trip form; `nan` (not Rust's `NaN`) for a missing one, as C
/// and the plotting tools write it.
fn push_ratio(out: &mut String, v: f64) {
    if v.is_nan() {
        out.push_str("nan");
    } else {
        push_shortest_exp(out, v);
    }
}

/// The first column of a time-stamped log (`int.log`, `w.log`, `gps.log`, ...), µs.
pub fn parse_time_column(f: &[&str]) -> Result<i64, String> {
    time_field(f, 0, "time")
}

/// The first two columns of a log as times (`kalman_in.log`: step time and IMU dt), µs.
pub fn parse_time_column_pair(f: &[&str]) -> Result<(i64, i64), String> {
    Ok((time_field(f, 0, "time")?, time_field(f, 1, "dt")?))
}

/// Writes a row of `%.15f` values, each followed by a tab, as the original's matrix dumps
/// (`x_hat.log`); `t_us` first when given (`w.log`, `int.log`).
pub fn write_values_row(out: &mut String, t_us: Option<i64>, values: &[f64]) {
    if let Some(t) = t_us {
        push_time_us(out, t);
        out.push('\t');
    }
    for v in values {
        push_fixed(out, *v, 15);
        out.push('\t');
    }
    out.push('\n');
}

/// A time-stamped row of four values (`w.log`: motor speeds m0..m3; `int.log`: integrators).
pub fn parse_time_and_4(f: &[&str]) -> Result<(i64, [f64; 4]), String> {
    parse_time_and::<4>(f)
}

/// A time-stamped row of `N` values (`setpoint.log`: 6).
pub fn parse_time_and<const N: usize>(f: &[&str]) -> Result<(i64, [f64; N]), String> {
    if f.len() != N + 1 {
        return Err(format!("expected {} columns, found {}", N + 1, f.len()));
    }
    let t = time_field(f, 0, "time")?;
    let mut v = [0.0; N];
    for (i, slot) in v.iter_mut().enumerate() {
        *slot = field(f, i + 1, "value")?;
    }
    Ok((t, v))
}

/// A row of `x_hat.log`: the 15 states.
pub fn parse_x_hat(f: &[&str]) -> Result<[f64; 15], String> {
    if f.len() != 15 {
        return Err(format!("expected 15 columns, found {}", f.len()));
    }
    let mut v = [0.0; 15];
    for (i, slot) in v.iter_mut().enumerate() {
        *slot = field(f, i, "state")?;
    }
    Ok(v)
}

/// First line of the gps.log uquad writes for gpsd fixes: columns 4–6 are then positions in the
/// local frame (x north, y west, z up from the first fix, m), printed to round-trip exactly.
pub const UQUAD_GPS_HEADER: &str = "# uquad gps.log: t_main gps_time fix x y z vx vy vz lat lon speed climb track vel_ok; x y z = local frame (north, west, up from the first fix), m";

/// Writes one fused gpsd fix in the 15 columns of spec 7.1 (the velocity, when the receiver
/// gave one, with vel_ok 1; else zeros and 0). `t_us` is
/// the time before which the fix was received, so a replay fuses it in the same step.
#[allow(clippy::too_many_arguments)]
pub fn write_gps_fix(
    out: &mut String,
    t_us: i64,
    stamp_us: i64,
    fix_mode: u8,
    pos_m: [f64; 3],
    vel_m_s: Option<[f64; 3]>,
    lat_deg: f64,
    lon_deg: f64,
) {
    push_time_us(out, t_us);
    out.push('\t');
    push_time_us(out, stamp_us);
    // `{}` prints the shortest text that reads back to the same f64. The velocity columns and
    // vel_ok (the last) say whether the receiver gave a velocity.
    let (v, ok) = vel_m_s.map_or(([0.0; 3], 0), |v| (v, 1));
    let _ = writeln!(
        out,
        "\t{fix_mode}\t{}\t{}\t{}\t{}\t{}\t{}\t{lat_deg}\t{lon_deg}\t0\t0\t0\t{ok}\t",
        pos_m[0], pos_m[1], pos_m[2], v[0], v[1], v[2]
    );
}

/// One `gps.log` line in either of the original's formats.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GpsLogRecord {
    /// Fake GPS (spec 7.4): only the time of the sample; the position was (0, 0, 0).
    TimeOnly { t_us: i64 },
    /// The gpsd client's 15 columns (spec 7.1): t_main, gps time, fix, x, y, z, vx, vy, vz, lat,
    /// lon, speed, climb, track, vel_ok. Only the fields the filter needs are kept.
    Gpsd {
        t_us: i64,
        fix_mode: i32,
        /// Columns 4–6: absolute UTM in the original's logs; the local-frame position in
        /// uquad's (whose gps.log starts with [`UQUAD_GPS_HEADER`]).
        pos_m: [f64; 3],
        /// Columns 7–9 when column 15 (vel_ok) is 1: the velocity in the local frame (uquad's
        /// logs).
        vel_m_s: Option<[f64; 3]>,
        lat_deg: f64,
        lon_deg: f64,
        alt_m: f64,
    },
}

impl GpsLogRecord {
    pub fn t_us(&self) -> i64 {
        match *self {
            GpsLogRecord::TimeOnly { t_us } | GpsLogRecord::Gpsd { t_us, .. } => t_us,
        }
    }

    pub fn parse_fields(f: &[&str]) -> Result<Self, String> {
        match f.len() {
            1 => Ok(GpsLogRecord::TimeOnly {
                t_us: time_field(f, 0, "t_main")?,
            }),
            15 => Ok(GpsLogRecord::Gpsd {
                t_us: time_field(f, 0, "t_main")?,
                fix_mode: field(f, 2, "fix")?,
                pos_m: [field(f, 3, "x")?, field(f, 4, "y")?, field(f, 5, "z")?],
                vel_m_s: match field::<f64>(f, 14, "vel_ok")? {
                    1.0 => Some([field(f, 6, "vx")?, field(f, 7, "vy")?, field(f, 8, "vz")?]),
                    _ => None,
                },
                alt_m: field(f, 5, "z")?,
                lat_deg: field(f, 9, "lat")?,
                lon_deg: field(f, 10, "lon")?,
            }),
            n => Err(format!(
                "expected 1 column (fake GPS time) or 15 (gpsd format), found {n}"
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_round_trip() {
        assert_eq!(parse_time_us("12.126526"), Some(12_126_526));
        assert_eq!(parse_time_us("0.5"), Some(500_000));
        assert_eq!(parse_time_us("3"), Some(3_000_000));
        assert_eq!(parse_time_us("1.0000005"), Some(1_000_001));
        assert_eq!(parse_time_us("-0.000001"), Some(-1));
        assert_eq!(parse_time_us("1.2e3"), None);
        assert_eq!(parse_time_us(""), None);
        assert_eq!(fmt_time_us(12_126_526), "12.126526");
        assert_eq!(fmt_time_us(5), "0.000005");
    }

    /// The plain reading, as times were parsed before the one-pass version: every character
    /// a digit but one point, checked arithmetic.
    fn reference_time_us(s: &str) -> Option<i64> {
        let bytes = s.as_bytes();
        let (neg, body) = match bytes.split_first() {
            Some((b'-', rest)) => (true, rest),
            _ => (false, bytes),
        };
        let (whole, frac) = match body.iter().position(|&c| c == b'.') {
            Some(dot) => (&body[..dot], &body[dot + 1..]),
            None => (body, &[][..]),
        };
        if whole.is_empty() && frac.is_empty() {
            return None;
        }
        if !whole.iter().chain(frac).all(u8::is_ascii_digit) {
            return None;
        }
        let mut secs: i64 = 0;
        for &c in whole {
            secs = secs.checked_mul(10)?.checked_add(i64::from(c - b'0'))?;
        }
        let mut micros: i64 = 0;
        for k in 0..6 {
            micros = micros * 10 + frac.get(k).map_or(0, |&c| i64::from(c - b'0'));
        }
        if frac.get(6).is_some_and(|&c| c >= b'5') {
            micros += 1;
        }
        let t = secs.checked_mul(1_000_000)?.checked_add(micros)?;
        Some(if neg { -t } else { t })
    }

    #[test]
    fn times_parse_as_the_plain_reading_does() {
        let mut cases: Vec<String> = [
            "",
            ".",
            "-",
            "-.",
            "0",
            "1.",
            ".5",
            "-0.0000005",
            "12.126526",
            "1.2e3",
            "1..2",
            "999999999999.999999",
            "999999999999.9999995",
            "1000000000000",
            "1 2",
            "+1",
            "1327662538.476410",
            "9223372036854.775807",
            "00000000000000001.5",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let mut x = 0x1234_5678u64;
        let alphabet = b"0123456789.-e ";
        for _ in 0..50_000 {
            let mut t = String::new();
            for _ in 0..(x % 22) {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                t.push(char::from(alphabet[(x % alphabet.len() as u64) as usize]));
            }
            cases.push(t);
        }
        for t in cases {
            assert_eq!(parse_time_us(&t), reference_time_us(&t), "{t:?}");
        }
    }

    #[test]
    fn line_ends_all_accepted() {
        for text in [
            "1\t\n2\t\n",
            "1\t\r\n2\t\r\n",
            "1\t\n\r2\t\n\r",
            "1\n  \n\r\n2",
        ] {
            let got: Vec<&str> = records(text).map(|(_, l)| l).collect();
            assert_eq!(got, vec!["1", "2"], "{text:?}");
        }
    }

    #[test]
    fn imu_raw_round_trip_and_errors() {
        let line = "7.039246\t1327662538.476410\t9996\t0\t7\t193\t-54\t17\t-22\t-141\t-268\t119\t386\t101443\n";
        let p = parse_log(line, ImuRawRecord::parse_fields).unwrap();
        let mut out = String::new();
        p.rows[0].write(&mut out);
        assert_eq!(out, line);
        let bad = format!("{line}{}", line.replace("193", "1x3")).repeat(2);
        let e = parse_log(&bad, ImuRawRecord::parse_fields).unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.message.contains("column 6"), "{e}");
        // A cut-off last line is dropped and reported.
        let cut = format!("{line}{}", &line[..20]);
        let p = parse_log(&cut, ImuRawRecord::parse_fields).unwrap();
        assert_eq!(p.rows.len(), 1);
        assert_eq!(p.truncated.unwrap().line, 2);
    }

    #[test]
    fn gps_log_formats() {
        let p = parse_log("12.135285\t\n\r13.137391\t\n", GpsLogRecord::parse_fields).unwrap();
        assert_eq!(p.rows[1], GpsLogRecord::TimeOnly { t_us: 13_137_391 });
        let line = "174.962037 1327671477.494110 3 576155.5929 6135556.1144 27.7 -0 -0 -0.1 -34.919588333 -56.166258333 0 -0.1 5.3075 1";
        let p = parse_log(line, GpsLogRecord::parse_fields).unwrap();
        assert_eq!(
            p.rows[0],
            GpsLogRecord::Gpsd {
                t_us: 174_962_037,
                fix_mode: 3,
                pos_m: [576_155.592_9, 6_135_556.114_4, 27.7],
                vel_m_s: Some([-0.0, -0.0, -0.1]),
                lat_deg: -34.919588333,
                lon_deg: -56.166258333,
                alt_m: 27.7
            }
        );
        assert!(parse_log("1 2 3\n", GpsLogRecord::parse_fields).is_err());
        // uquad's own gpsd lines round-trip the local position exactly, behind a header.
        let mut ours = format!("{UQUAD_GPS_HEADER}\n");
        let pos = [0.1 + 0.2, -13.426_443_214_528_263, 1e-300];
        let vel = [0.3 - 0.1, -1e-7, 2.0 / 3.0];
        write_gps_fix(
            &mut ours, 12_000_001, 11_999_000, 3, pos, None, -34.9193, -56.167_14,
        );
        write_gps_fix(
            &mut ours,
            13_000_001,
            12_999_000,
            3,
            pos,
            Some(vel),
            -34.9193,
            -56.167_14,
        );
        let p = parse_log(&ours, GpsLogRecord::parse_fields).unwrap();
        assert!(matches!(
            p.rows[0],
            GpsLogRecord::Gpsd { pos_m, t_us: 12_000_001, vel_m_s: None, .. } if pos_m == pos
        ));
        // And the velocity, when the receiver gave one.
        assert!(matches!(
            p.rows[1],
            GpsLogRecord::Gpsd { vel_m_s: Some(v), .. } if v == vel
        ));
    }

    #[test]
    fn fixed_formatting_equals_the_standard_formatter() {
        let mut values = vec![
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.5,
            0.25,
            0.125,
            2.5,
            1e-20,
            -1e-20,
            5e-324,
            123.456,
            229.843_428_625_595_27,
            368.0,
            1e16,
            9.999_999_999_999_999e16,
            0.000_000_5,
            0.000_000_015,
            -0.000_000_025,
            1_327_662_538.476_41,
        ];
        let mut x = 0x1234_5678_9abc_def0u64;
        for _ in 0..20_000 {
            // xorshift: arbitrary bit patterns, then scaled into the logs' usual ranges.
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let v = f64::from_bits(x);
            if v.is_finite() {
                values.push(v % 1e5);
                values.push((x >> 11) as f64 / (1u64 << 53) as f64 - 0.5);
            }
        }
        for v in values {
            for d in 0..=15 {
                let mut ours = String::new();
                push_fixed(&mut ours, v, d);
                assert_eq!(
                    ours,
                    format!("{v:.*}", d as usize),
                    "{v:e} with {d} decimals"
                );
            }
        }
    }

    #[test]
    fn values_rows() {
        let mut out = String::new();
        write_values_row(&mut out, Some(12_134_736), &[248.5, -0.25, 0.0, 1.0]);
        assert_eq!(
            out,
            "12.134736\t248.500000000000000\t-0.250000000000000\t0.000000000000000\t1.000000000000000\t\n"
        );
        let p = parse_log(&out, parse_time_and_4).unwrap();
        assert_eq!(p.rows[0], (12_134_736, [248.5, -0.25, 0.0, 1.0]));
    }

    #[test]
    fn innov_round_trip() {
        let rows = [
            InnovRecord {
                t_us: 12_136_963,
                ratios: TestRatios {
                    attitude: 4.0e-8,
                    altitude: 1.0 / 3.0,
                    gps: None,
                },
                gated: GatedGroups::default(),
            },
            InnovRecord {
                t_us: 12_146_963,
                ratios: TestRatios {
                    attitude: 4.25,
                    altitude: 0.0,
                    gps: Some(1e300),
                },
                gated: GatedGroups {
                    attitude: true,
                    altitude: false,
                    gps: true,
                },
            },
        ];
        let mut text = String::new();
        for r in &rows {
            r.write(&mut text);
        }
        assert_eq!(
            text,
            "12.136963\t4e-8\t3.333333333333333e-1\tnan\t0\n12.146963\t4.25e0\t0e0\t1e300\t5\n"
        );
        let p = parse_log(&text, InnovRecord::parse_fields).unwrap();
        assert_eq!(p.rows, rows);
        assert!(parse_log("1.0\t1\t1\tnan\t8\n", InnovRecord::parse_fields).is_err());
    }

    #[test]
    fn kalman_in_round_trip() {
        let line = "12.136963\t0.010529\t0.00000000\t-0.19719096\t-0.09051753\t9.84725062\t-0.00002714\t0.01392673\t0.00301638\t-0.00919190\t0.02002145\t2.02196493\t38.30000000\t-0.49892002\n";
        let p = parse_log(line, KalmanInRecord::parse_fields).unwrap();
        let mut out = String::new();
        p.rows[0].write(&mut out);
        assert_eq!(out, line);
    }
}
