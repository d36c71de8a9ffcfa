//! Fuzzing on the stable toolchain: the readers of outside data take generated inputs and must
//! never panic. One test per reader:
//!
//! - `imu_frames`: the binary frame decoder (`FrameDecoder::next_frame`, any split of the
//!   stream), `RawFrame::parse` and the ASCII debug frame `RawFrame::from_ascii`;
//! - `gpsd_reports`: gpsd's JSON lines (`parse_report`), their fixes (`Tpv::fix`) and the
//!   conversion of any latitude/longitude to UTM and the local frame;
//! - `console_lines`: the console's line reader (the codec and limit `console::client` uses)
//!   and its commands (`console::command`, `Filter`, `RateLimit`);
//! - `config_loader`: `config::load` of generated TOML with generated `--set` overrides
//!   (`parse_set`), and what a loaded profile builds;
//! - `log_readers`: `parse_log` with every record parser of `logs::format`, `parse_time_us`,
//!   and the fixed-point printer the logs are written with;
//! - `mavlink_frames`: the ground-station link's MAVLink decoder (`gcs::wire::Decoder`, as
//!   datagrams and as a stream cut anywhere), the command mapping and parameter values.
//! - `rc_frames`: the RC receiver's SBUS and CRSF decoders (`core::rc`, any split of the
//!   stream), `sbus::parse`, and each protocol's frames decoded back to what was encoded.
//!
//! Each takes random input and structure-aware mutations of valid input (frames with bytes
//! flipped, a TPV report with fields changed or cut, a shipped profile with values replaced by
//! odd numbers, strings, NaN or huge integers, log lines with fields mangled), so the inputs
//! get past the first check. Each also checks a cheap property (bytes accounted for, a parsed
//! record re-encodes to itself, a loaded profile reloads to the same configuration, ...).
//!
//! `UQUAD_FUZZ_CASES` sets the number of cases per target (default 2000, which keeps the test
//! command fast); the seed is fixed unless `UQUAD_FUZZ_SEED` gives one, which also replays a
//! run (each test prints its seed). A failing case
//! is shrunk by proptest and printed with the seed. The long run (docs/src/fuzzing.md):
//!
//! ```sh
//! UQUAD_FUZZ_CASES=1000000 cargo test --release --test fuzz -- --test-threads=1 --nocapture
//! ```

use bytes::BytesMut;
use proptest::collection::vec;
use proptest::prelude::*;
use proptest::sample::{Index, select};
use proptest::test_runner::{Config, RngSeed, TestCaseError, TestError, TestRunner};
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio_util::codec::{Decoder, LinesCodec};
use uquad::core::imu::frame::{AsciiFrameError, FRAME_LEN, FrameDecoder, RawFrame, is_start_byte};

// ---------------------------------------------------------------------------------------------
// The runner
// ---------------------------------------------------------------------------------------------

/// Cases per target: `UQUAD_FUZZ_CASES`, default 2000.
fn cases() -> u32 {
    std::env::var("UQUAD_FUZZ_CASES")
        .ok()
        .and_then(|v| v.trim().replace('_', "").parse().ok())
        .unwrap_or(2000)
}

/// `UQUAD_FUZZ_SEED`, else a fixed one: the test command explores the same inputs on every
/// run (a failure is never luck); long runs pass seeds of their own.
fn seed() -> u64 {
    std::env::var("UQUAD_FUZZ_SEED")
        .ok()
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(20_261_124)
}

/// How many cases reached each outcome, to see that the inputs get past the first checks.
#[derive(Default)]
struct Tally(std::cell::RefCell<std::collections::BTreeMap<&'static str, u64>>);

impl Tally {
    fn add(&self, outcome: &'static str) {
        *self.0.borrow_mut().entry(outcome).or_default() += 1;
    }
}

/// Runs `test` on `cases()` inputs of `strategy`. A failure (a panic included: proptest catches
/// it) is shrunk, then reported with the smallest failing input and the seed to replay it.
/// Prints the time taken and the outcomes counted in `tally`.
fn fuzz<S>(
    name: &str,
    strategy: S,
    tally: &Tally,
    test: impl Fn(S::Value) -> Result<(), TestCaseError>,
) where
    S: Strategy,
    S::Value: fmt::Debug,
{
    let (cases, seed) = (cases(), seed());
    eprintln!("fuzz {name}: {cases} cases, UQUAD_FUZZ_SEED={seed}");
    let config = Config {
        cases,
        failure_persistence: None,
        rng_seed: RngSeed::Fixed(seed),
        ..Config::default()
    };
    let start = Instant::now();
    match TestRunner::new(config).run(&strategy, test) {
        Ok(()) => eprintln!(
            "fuzz {name}: {cases} cases passed in {:.1} s; outcomes {:?}",
            start.elapsed().as_secs_f64(),
            tally.0.borrow()
        ),
        Err(TestError::Fail(reason, input)) => panic!(
            "fuzz {name}: {reason}\nsmallest failing input: {input:#?}\n\
             replay with UQUAD_FUZZ_SEED={seed} UQUAD_FUZZ_CASES={cases}"
        ),
        Err(TestError::Abort(reason)) => panic!("fuzz {name}: aborted: {reason}"),
    }
}

/// Bytes, shown as hex and as lossy text when a case fails.
#[derive(Clone, PartialEq)]
struct Hex(Vec<u8>);

impl fmt::Debug for Hex {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let hex: Vec<String> = self.0.iter().map(|b| format!("{b:02x}")).collect();
        write!(
            f,
            "{} bytes [{}] {:?}",
            self.0.len(),
            hex.join(" "),
            String::from_utf8_lossy(&self.0)
        )
    }
}

// ---------------------------------------------------------------------------------------------
// Generic mutations
// ---------------------------------------------------------------------------------------------

/// An edit of a byte string.
#[derive(Debug, Clone)]
enum ByteEdit {
    Flip(Index, u8),
    Set(Index, u8),
    Delete(Index, usize),
    Insert(Index, Vec<u8>),
    Truncate(Index),
    Duplicate(Index, usize),
}

/// Bytes that matter to the frame format.
fn interesting_byte() -> impl Strategy<Value = u8> {
    prop_oneof![
        select(vec![b'A', b'C', b'Z', 0, 0xff, b'\n', b'\r', b'\t', 0x80]),
        any::<u8>()
    ]
}

fn byte_edit() -> impl Strategy<Value = ByteEdit> {
    prop_oneof![
        (any::<Index>(), 0u8..8).prop_map(|(i, b)| ByteEdit::Flip(i, b)),
        (any::<Index>(), interesting_byte()).prop_map(|(i, b)| ByteEdit::Set(i, b)),
        (any::<Index>(), 1usize..40).prop_map(|(i, n)| ByteEdit::Delete(i, n)),
        (any::<Index>(), vec(interesting_byte(), 1..40)).prop_map(|(i, b)| ByteEdit::Insert(i, b)),
        any::<Index>().prop_map(ByteEdit::Truncate),
        (any::<Index>(), 1usize..64).prop_map(|(i, n)| ByteEdit::Duplicate(i, n)),
    ]
}

fn apply_byte_edit(b: &mut Vec<u8>, e: &ByteEdit) {
    let at = |i: &Index, len: usize| i.index(len + 1);
    match e {
        ByteEdit::Flip(i, bit) if !b.is_empty() => {
            let k = i.index(b.len());
            b[k] ^= 1 << bit;
        }
        ByteEdit::Set(i, v) if !b.is_empty() => {
            let k = i.index(b.len());
            b[k] = *v;
        }
        ByteEdit::Delete(i, n) => {
            let k = at(i, b.len());
            let end = (k + n).min(b.len());
            b.drain(k..end);
        }
        ByteEdit::Insert(i, v) => {
            let k = at(i, b.len());
            b.splice(k..k, v.iter().copied());
        }
        ByteEdit::Truncate(i) => b.truncate(at(i, b.len())),
        ByteEdit::Duplicate(i, n) => {
            let k = at(i, b.len());
            let end = (k + n).min(b.len());
            let copy = b[k..end].to_vec();
            b.splice(end..end, copy);
        }
        _ => {}
    }
}

/// An edit of a text.
#[derive(Debug, Clone)]
enum TextEdit {
    Insert(Index, String),
    Delete(Index, usize),
    Truncate(Index),
    Duplicate(Index, usize),
}

/// The largest char boundary of `s` at or before `i.index(len + 1)`.
fn boundary(s: &str, i: &Index) -> usize {
    let mut k = i.index(s.len() + 1);
    while !s.is_char_boundary(k) {
        k -= 1;
    }
    k
}

fn text_edit(tokens: &'static [&'static str]) -> impl Strategy<Value = TextEdit> {
    prop_oneof![
        (any::<Index>(), odd_text(tokens)).prop_map(|(i, s)| TextEdit::Insert(i, s)),
        (any::<Index>(), 1usize..20).prop_map(|(i, n)| TextEdit::Delete(i, n)),
        any::<Index>().prop_map(TextEdit::Truncate),
        (any::<Index>(), 1usize..60).prop_map(|(i, n)| TextEdit::Duplicate(i, n)),
    ]
}

fn apply_text_edit(s: &mut String, e: &TextEdit) {
    match e {
        TextEdit::Insert(i, t) => {
            let k = boundary(s, i);
            s.insert_str(k, t);
        }
        TextEdit::Delete(i, n) => {
            let k = boundary(s, i);
            let end = s[k..]
                .char_indices()
                .nth(*n)
                .map_or(s.len(), |(j, _)| k + j);
            s.replace_range(k..end, "");
        }
        TextEdit::Truncate(i) => {
            let k = boundary(s, i);
            s.truncate(k);
        }
        TextEdit::Duplicate(i, n) => {
            let k = boundary(s, i);
            let end = s[k..]
                .char_indices()
                .nth(*n)
                .map_or(s.len(), |(j, _)| k + j);
            let copy = s[k..end].to_string();
            s.insert_str(end, &copy);
        }
    }
}

/// Numbers and words that break parsers: signs alone, overflowing integers, non-finite and
/// extreme floats, exponents, unicode digits and spaces, control characters.
const ODD_NUMBERS: &[&str] = &[
    "",
    "-",
    "+",
    ".",
    "-.",
    "0",
    "-0",
    "+1",
    "1.",
    ".5",
    "-.5",
    "00000000000000000000001",
    "127",
    "128",
    "255",
    "256",
    "-129",
    "32767",
    "32768",
    "-32768",
    "-32769",
    "65535",
    "65536",
    "2147483647",
    "2147483648",
    "-2147483649",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "9223372036854775808",
    "-9223372036854775808",
    "-9223372036854775809",
    "18446744073709551616",
    "99999999999999999999999999999",
    "9223372036854.775807",
    "9223372036854.775808",
    "-9223372036854.775808",
    "0.0000005",
    "1.9999995",
    "1.99999999999999999999",
    "1e3",
    "1E-3",
    "1e308",
    "1e309",
    "-1e400",
    "5e-324",
    "4.9e-325",
    "1.7976931348623157e308",
    "nan",
    "NaN",
    "-nan",
    "inf",
    "-inf",
    "infinity",
    "Infinity",
    "0x10",
    "0b1",
    "1_000",
    "1,5",
    "١٢",
    "\u{a0}1",
    "1\u{2003}",
    "\u{0}",
    "\u{feff}",
    "é",
    "🚁",
];

/// A token from `tokens` or [`ODD_NUMBERS`], or random characters.
fn odd_text(tokens: &'static [&'static str]) -> impl Strategy<Value = String> {
    prop_oneof![
        3 => select(ODD_NUMBERS).prop_map(str::to_string),
        3 => select(tokens).prop_map(str::to_string),
        1 => any::<i64>().prop_map(|v| v.to_string()),
        1 => any::<f64>().prop_map(|v| v.to_string()),
        1 => vec(any::<char>(), 0..8).prop_map(|c| c.into_iter().collect()),
    ]
}

// ---------------------------------------------------------------------------------------------
// 1. IMU frames
// ---------------------------------------------------------------------------------------------

fn arb_frame() -> impl Strategy<Value = RawFrame> {
    (
        any::<u32>(),
        any::<[i16; 3]>(),
        any::<[i16; 3]>(),
        any::<[i16; 3]>(),
        any::<i16>(),
        any::<u32>(),
    )
        .prop_map(|(t_us, acc, gyro, magn, temp_dc, pres_pa)| RawFrame {
            t_us,
            acc,
            gyro,
            magn,
            temp_dc,
            pres_pa,
        })
}

/// A byte stream: random, random over the format's own bytes, or valid frames mutated.
fn frame_stream() -> impl Strategy<Value = Hex> {
    prop_oneof![
        vec(any::<u8>(), 0..300),
        vec(interesting_byte(), 0..300),
        (
            vec(arb_frame(), 1..6),
            vec(interesting_byte(), 0..8),
            vec(byte_edit(), 0..6)
        )
            .prop_map(|(frames, lead, edits)| {
                let mut b = lead;
                for (k, f) in frames.iter().enumerate() {
                    b.extend(f.encode(if k % 2 == 0 { b'A' } else { b'C' }));
                }
                for e in &edits {
                    apply_byte_edit(&mut b, e);
                }
                b
            }),
    ]
    .prop_map(Hex)
}

/// Feeds `bytes` to a fresh decoder in `chunks` (cycled) and checks every step: what the
/// decoder consumed is exactly its frames and its discarded bytes, each frame re-encodes to the
/// 30 bytes it was read from, and what it leaves buffered is less than a frame starting with a
/// start byte.
fn decode_checked(bytes: &[u8], chunks: &[usize]) -> Result<Vec<RawFrame>, TestCaseError> {
    let mut d = FrameDecoder::new();
    let mut buf = BytesMut::new();
    let mut frames = Vec::new();
    let (mut fed, mut k) = (0usize, 0usize);
    while fed < bytes.len() {
        let n = chunks[k % chunks.len()].clamp(1, bytes.len() - fed);
        buf.extend_from_slice(&bytes[fed..fed + n]);
        fed += n;
        while let Some(f) = d.next_frame(&mut buf) {
            let end = fed - buf.len();
            prop_assert!(end >= FRAME_LEN, "a frame out of {end} bytes");
            let start = end - FRAME_LEN;
            prop_assert_eq!(&f.encode(bytes[start])[..], &bytes[start..end]);
            frames.push(f);
        }
        k += 1;
        let s = d.stats();
        prop_assert_eq!(s.frames as usize, frames.len());
        prop_assert!(s.rejected_frames <= s.discarded_bytes);
        let consumed = frames.len() * FRAME_LEN + s.discarded_bytes as usize;
        prop_assert_eq!(
            consumed + buf.len(),
            fed,
            "bytes consumed + left != bytes fed"
        );
        prop_assert!(buf.len() < FRAME_LEN);
        prop_assert!(buf.is_empty() || is_start_byte(buf[0]));
    }
    Ok(frames)
}

/// An ASCII debug line: random text, or a frame's line with fields, separators or line end
/// mangled.
fn ascii_line() -> impl Strategy<Value = String> {
    const TOKENS: &[&str] = &["A", "C", "Z", "\t", "\r", "\n", "\r\n", " ", "\t\t"];
    prop_oneof![
        1 => vec(any::<char>(), 0..80).prop_map(|c| c.into_iter().collect()),
        3 => (
            arb_frame(),
            vec((any::<Index>(), odd_text(TOKENS)), 0..3),
            prop_oneof![3 => Just(Vec::new()), 1 => vec(text_edit(TOKENS), 1..3)]
        )
            .prop_map(|(f, fields, edits)| {
                let line = f.to_ascii();
                let mut parts: Vec<String> = line.split('\t').map(str::to_string).collect();
                for (i, t) in fields {
                    let k = i.index(parts.len());
                    parts[k] = t;
                }
                let mut s = parts.join("\t");
                for e in &edits {
                    apply_text_edit(&mut s, e);
                }
                s
            }),
    ]
}

#[test]
fn imu_frames() {
    let strategy = (
        frame_stream(),
        vec(1usize..80, 1..6),
        any::<[u8; FRAME_LEN]>(),
        ascii_line(),
    );
    let tally = Tally::default();
    fuzz(
        "imu_frames",
        strategy,
        &tally,
        |(bytes, chunks, candidate, line)| {
            let bytes = &bytes.0;
            // However the stream is split, the same frames.
            let split = decode_checked(bytes, &chunks)?;
            let whole = decode_checked(bytes, &[bytes.len().max(1)])?;
            prop_assert_eq!(&split, &whole);
            tally.add(if split.is_empty() {
                "stream: no frame"
            } else {
                "stream: frames"
            });

            // A candidate parses exactly when its start and end bytes are right, and re-encodes to
            // itself.
            let mut c = candidate;
            if c[0] % 2 == 0 {
                c[0] = b'A';
                c[FRAME_LEN - 1] = b'Z';
            }
            match RawFrame::parse(&c) {
                Some(f) => {
                    tally.add("candidate: frame");
                    prop_assert!(is_start_byte(c[0]) && c[FRAME_LEN - 1] == b'Z');
                    prop_assert_eq!(f.encode(c[0]), c)
                }
                None => prop_assert!(!is_start_byte(c[0]) || c[FRAME_LEN - 1] != b'Z'),
            }

            // An ASCII line that parses prints back to a line that parses to the same frame.
            let ascii = RawFrame::from_ascii(&line);
            tally.add(match &ascii {
                Ok(_) => "ascii: frame",
                Err(AsciiFrameError::FieldCount(_)) => "ascii: field count",
                Err(AsciiFrameError::Markers) => "ascii: markers",
                Err(AsciiFrameError::Number { .. }) => "ascii: number",
            });
            if let Ok(f) = ascii {
                prop_assert_eq!(RawFrame::from_ascii(&f.to_ascii()), Ok(f));
            }
            Ok(())
        },
    );
}

// ---------------------------------------------------------------------------------------------
// 2. gpsd JSON reports
// ---------------------------------------------------------------------------------------------

use serde_json::{Value as Json, json};
use uquad::core::gps::{LocalFrame, Report, deg_to_utm, parse_report};

/// A line gpsd 3.22 wrote (a 3-D fix in Montevideo).
const TPV_3D: &str = r#"{"class":"TPV","device":"tcp://127.0.0.1:29471","mode":3,"time":"2031-09-15T12:00:04.000Z","ept":0.005,"lat":-34.919588333,"lon":-56.166258333,"altHAE":41.7000,"altMSL":27.7000,"alt":27.7000,"epv":27.600,"track":0.0000,"magtrack":349.0664,"magvar":-10.9,"speed":0.000,"climb":0.000,"epc":55.20,"geoidSep":14.000,"eph":1.800,"sep":3.000}"#;

/// Fields the reader looks at, and some it does not.
const GPSD_FIELDS: &[&str] = &[
    "class",
    "mode",
    "lat",
    "lon",
    "alt",
    "altMSL",
    "altHAE",
    "time",
    "epx",
    "epy",
    "epv",
    "satellites",
    "PRN",
    "used",
    "release",
    "proto_major",
    "proto_minor",
    "message",
    "device",
    "devices",
    "",
];

/// JSON values of every kind and the numbers at the edges of the fields' types.
fn odd_json() -> impl Strategy<Value = Json> {
    let leaf = prop_oneof![
        select(vec![
            json!(null),
            json!(true),
            json!(false),
            json!(0),
            json!(-1),
            json!(1),
            json!(2),
            json!(3),
            json!(4),
            json!(255),
            json!(256),
            json!(-129),
            json!(u32::MAX),
            json!(u64::MAX),
            json!(i64::MIN),
            json!(90.0),
            json!(-90.0),
            json!(180.0),
            json!(-180.0),
            json!(90.000001),
            json!(-180.000001),
            json!(1e308),
            json!(-1.7976931348623157e308),
            json!(5e-324),
            json!(-0.0),
            json!(""),
            json!("3"),
            json!("nan"),
            json!("TPV"),
            json!("SKY"),
            json!("VERSION"),
            json!("DEVICES"),
            json!("WATCH"),
            json!("ERROR"),
            json!("PPS"),
            json!("\u{0}"),
        ]),
        any::<f64>().prop_map(|v| serde_json::Number::from_f64(v).map_or(Json::Null, Json::Number)),
        any::<i64>().prop_map(|v| json!(v)),
        vec(any::<char>(), 0..8).prop_map(|c| Json::String(c.into_iter().collect())),
    ];
    leaf.prop_recursive(2, 8, 3, |inner| {
        prop_oneof![
            vec(inner.clone(), 0..3).prop_map(Json::Array),
            vec((select(GPSD_FIELDS), inner), 0..3).prop_map(|kv| {
                Json::Object(kv.into_iter().map(|(k, v)| (k.to_string(), v)).collect())
            }),
        ]
    })
}

/// A report as gpsd sends it: a TPV with generated fix fields, or one of the other classes.
fn gpsd_report() -> impl Strategy<Value = Json> {
    prop_oneof![
        4 => (0u8..5, -90.0..=90.0f64, -180.0..=180.0f64, -500.0..9000.0f64, any::<u8>())
            .prop_map(|(mode, lat, lon, alt, which)| {
                let mut r = json!({"class": "TPV", "device": "/dev/ttyUSB0", "mode": mode,
                    "time": "2012-05-25T11:08:45.000Z", "lat": lat, "lon": lon, "epx": 3.1});
                match which % 3 {
                    0 => r["altMSL"] = json!(alt),
                    1 => r["alt"] = json!(alt),
                    _ => r["altHAE"] = json!(alt),
                }
                r
            }),
        1 => Just(serde_json::from_str::<Json>(TPV_3D).expect("a valid report")),
        1 => Just(json!({"class": "SKY", "satellites": [{"PRN": 1, "used": true}, {"PRN": 2}]})),
        1 => Just(json!({"class": "VERSION", "release": "3.22", "proto_major": 3, "proto_minor": 14})),
        1 => Just(json!({"class": "DEVICES", "devices": [{"class": "DEVICE", "path": "/dev/ttyUSB0"}]})),
        1 => Just(json!({"class": "WATCH", "enable": true, "json": true})),
        1 => Just(json!({"class": "ERROR", "message": "unrecognized request"})),
    ]
}

#[derive(Debug, Clone)]
enum JsonEdit {
    Set(&'static str, Json),
    Remove(&'static str),
}

/// A gpsd line: random text, JSON-like soup, or a valid report with fields changed or removed
/// and its text cut or spliced.
fn gpsd_line() -> impl Strategy<Value = String> {
    const TOKENS: &[&str] = &[
        "{",
        "}",
        "[",
        "]",
        ",",
        ":",
        "\"",
        "\\",
        "\\u0000",
        "\\ud800",
        "\\uDFFF",
        "\"class\":",
        "\"TPV\"",
        "\"mode\":3",
        "null",
        "true",
        "1e400",
        "-1e400",
        "NaN",
        "Infinity",
        "-0",
        "\n",
        "\u{0}",
    ];
    prop_oneof![
        1 => vec(any::<char>(), 0..100).prop_map(|c| c.into_iter().collect()),
        1 => vec(select(TOKENS), 0..30).prop_map(|t| t.concat()),
        6 => (
            gpsd_report(),
            vec(
                prop_oneof![
                    (select(GPSD_FIELDS), odd_json()).prop_map(|(k, v)| JsonEdit::Set(k, v)),
                    select(GPSD_FIELDS).prop_map(JsonEdit::Remove),
                ],
                0..3
            ),
            prop_oneof![3 => Just(Vec::new()), 1 => vec(text_edit(TOKENS), 1..3)]
        )
            .prop_map(|(mut report, edits, text_edits)| {
                if let Json::Object(m) = &mut report {
                    for e in edits {
                        match e {
                            JsonEdit::Set(k, v) => {
                                m.insert(k.to_string(), v);
                            }
                            JsonEdit::Remove(k) => {
                                m.remove(k);
                            }
                        }
                    }
                }
                let mut s = report.to_string();
                for e in &text_edits {
                    apply_text_edit(&mut s, e);
                }
                s
            }),
    ]
}

/// Any latitude or longitude: in range, at the edges, just outside, extreme, not finite.
fn coordinate(limit: f64) -> impl Strategy<Value = f64> {
    prop_oneof![
        3 => -limit..=limit,
        2 => select(vec![
            0.0, -0.0, limit, -limit, limit - 1e-12, -limit + 1e-12, limit + 1e-9, -limit - 1e-9,
            84.0, -80.0, 6.0, -6.0, 3.0, 177.0, -177.0, 1e9, -1e9, 1e300, -1e300,
            f64::MAX, f64::MIN, f64::MIN_POSITIVE, 5e-324, f64::INFINITY, f64::NEG_INFINITY,
            f64::NAN,
        ]),
        1 => any::<f64>(),
    ]
}

#[test]
fn gpsd_reports() {
    let strategy = (
        gpsd_line(),
        vec((coordinate(90.0), coordinate(180.0), coordinate(1e4)), 1..4),
    );
    let tally = Tally::default();
    fuzz("gpsd_reports", strategy, &tally, |(line, points)| {
        let report = parse_report(&line);
        tally.add(match &report {
            Ok(Report::Tpv(t)) if t.fix().is_some() => "TPV with a fix",
            Ok(Report::Tpv(_)) => "TPV without a fix",
            Ok(_) => "other class",
            Err(_) => "refused",
        });
        if let Ok(Report::Tpv(tpv)) = report
            && let Some(fix) = tpv.fix()
        {
            prop_assert!(fix.mode >= 2);
            prop_assert!(fix.lat_deg.abs() <= 90.0 && fix.lon_deg.abs() <= 180.0);
            prop_assert!(fix.alt_m.is_none_or(f64::is_finite));
            // A fix as the gps client and `uquad gps` take it: into the local frame, twice
            // (the first becomes the origin).
            let mut frame = LocalFrame::default();
            let origin = frame.to_local(fix.lat_deg, fix.lon_deg, fix.alt_m);
            prop_assert_eq!(origin.xy_m, [0.0, 0.0]);
            prop_assert_eq!(origin.z_m, fix.alt_m.map(|_| 0.0));
            let again = frame.to_local(fix.lat_deg, fix.lon_deg, fix.alt_m);
            prop_assert_eq!(again, origin);
        }
        // Any coordinates (replay converts an original gps.log's unchecked ones).
        let mut frame = LocalFrame::default();
        for (lat, lon, alt) in points {
            let utm = deg_to_utm(lat, lon);
            let _ = frame.to_local(lat, lon, Some(alt));
            if lat.abs() < 90.0 && lon.abs() <= 180.0 {
                prop_assert!(
                    utm.easting_m.is_finite() && utm.northing_m.is_finite(),
                    "{utm:?}"
                );
                prop_assert!((1..=61).contains(&utm.zone), "{utm:?}");
            }
        }
        Ok(())
    });
}

// ---------------------------------------------------------------------------------------------
// 3. Console lines
// ---------------------------------------------------------------------------------------------

use uquad::console::{Filter, MAX_COMMANDS_PER_S, MAX_LINE_BYTES, RateLimit, command};
use uquad::core::commander::OperatorInput;

const CONSOLE_TOKENS: &[&str] = &[
    "filter",
    "filter ",
    "quit",
    "esc",
    "trace",
    "debug",
    "info",
    "warn",
    "error",
    "TRACE",
    "Warn",
    "off",
    "esc_writer",
    ",",
    " ",
    "\t",
    "\r",
    "\n",
    "j",
    "g",
    "y",
    "h",
    "q",
    "w",
    "e",
    "d",
    "i",
    "k",
    "0",
    "\u{1b}",
    "é",
    "\u{0}",
];

/// What a console sends: lines (random, keys, filters), or a raw byte stream in chunks.
#[derive(Debug, Clone)]
enum ConsoleInput {
    Lines(Vec<String>),
    Wire(Hex, Vec<usize>),
}

fn console_input() -> impl Strategy<Value = ConsoleInput> {
    let line = prop_oneof![
        vec(select(CONSOLE_TOKENS), 0..6).prop_map(|t| t.concat()),
        vec(any::<char>(), 0..20).prop_map(|c| c.into_iter().collect()),
        any::<char>().prop_map(|c| c.to_string()),
        (select(CONSOLE_TOKENS), odd_text(CONSOLE_TOKENS)).prop_map(|(a, b)| format!("{a}{b}")),
    ];
    let wire_byte = prop_oneof![
        3 => select(b"jgyhqwedik0 \n\r,filter".to_vec()),
        1 => any::<u8>(),
    ];
    prop_oneof![
        3 => vec(line, 1..8).prop_map(ConsoleInput::Lines),
        1 => (
            prop_oneof![
                vec(wire_byte, 0..200),
                // Long enough to pass the line limit.
                (1usize..3 * MAX_LINE_BYTES, any::<u8>(), 0usize..4).prop_map(|(n, b, nl)| {
                    let mut v = vec![b; n];
                    v.extend(std::iter::repeat_n(b'\n', nl));
                    v
                }),
            ],
            vec(1usize..600, 1..4)
        )
            .prop_map(|(b, c)| ConsoleInput::Wire(Hex(b), c)),
    ]
}

/// One console line through `command`, with what it must answer.
fn console_line(
    tally: &Tally,
    line: &str,
    filter: &mut Filter,
    tx: &tokio::sync::mpsc::Sender<OperatorInput>,
    rx: &mut tokio::sync::mpsc::Receiver<OperatorInput>,
) -> Result<(), TestCaseError> {
    let reply = command(line, filter, tx);
    tally.add(match reply.split_whitespace().nth(1) {
        None => "empty",
        Some("filter") => "filter",
        Some("sent") => "sent",
        Some("the") => "refused: queue full",
        Some("unknown") => "unknown",
        Some(_) => "other",
    });
    let t = line.trim();
    prop_assert_eq!(reply.is_empty(), t.is_empty(), "reply {:?}", reply);
    if let Some(rest) = t.strip_prefix("filter") {
        prop_assert_eq!(&*filter, &Filter::parse(rest));
    }
    if reply.starts_with("console: sent") {
        prop_assert!(rx.try_recv().is_ok(), "a sent command is queued");
        while rx.try_recv().is_ok() {}
    }
    // Every event passes a trace filter; an error passes any level.
    prop_assert!(Filter::parse("trace").accepts(line));
    let _ = filter.accepts(line);
    Ok(())
}

#[test]
fn console_lines() {
    let strategy = (console_input(), vec(0u64..400, 0..30), any::<bool>());
    let tally = Tally::default();
    fuzz(
        "console_lines",
        strategy,
        &tally,
        |(input, gaps_ms, backwards)| {
            // A queue of 2: commands beyond it are refused with a reply, as with a busy
            // controller.
            let (tx, mut rx) = tokio::sync::mpsc::channel(2);
            let mut filter = Filter::parse("info");
            match input {
                ConsoleInput::Lines(lines) => {
                    for l in &lines {
                        console_line(&tally, l, &mut filter, &tx, &mut rx)?;
                    }
                }
                ConsoleInput::Wire(bytes, chunks) => {
                    // The client's reader: lines capped at MAX_LINE_BYTES; an error disconnects.
                    let mut codec = LinesCodec::new_with_max_length(MAX_LINE_BYTES);
                    let mut buf = BytesMut::new();
                    let (mut at, mut k) = (0usize, 0usize);
                    'read: while at < bytes.0.len() {
                        let n = chunks[k % chunks.len()].min(bytes.0.len() - at);
                        k += 1;
                        buf.extend_from_slice(&bytes.0[at..at + n]);
                        at += n;
                        loop {
                            match codec.decode(&mut buf) {
                                Ok(Some(l)) => {
                                    prop_assert!(l.len() <= MAX_LINE_BYTES);
                                    console_line(&tally, &l, &mut filter, &tx, &mut rx)?;
                                }
                                Ok(None) => break,
                                Err(_) => {
                                    tally.add("line reader: disconnect");
                                    break 'read;
                                }
                            }
                        }
                    }
                }
            }
            // The rate limit: at most MAX_COMMANDS_PER_S in the first second, whatever the
            // gaps; the clock may also step back.
            let mut rate = RateLimit::default();
            let t0 = Instant::now();
            let mut t = t0;
            let mut first_second = 0;
            for (k, g) in gaps_ms.iter().enumerate() {
                t = if backwards && k % 3 == 2 {
                    t.checked_sub(Duration::from_millis(*g)).unwrap_or(t)
                } else {
                    t + Duration::from_millis(*g)
                };
                let ok = rate.allows(t);
                if ok && !backwards && t.duration_since(t0) < Duration::from_secs(1) {
                    first_second += 1;
                }
            }
            prop_assert!(first_second <= MAX_COMMANDS_PER_S);
            Ok(())
        },
    );
}

// ---------------------------------------------------------------------------------------------
// 4. The configuration loader
// ---------------------------------------------------------------------------------------------

use toml::Value as Toml;
use uquad::config::{load, parse_set};

/// The data files a profile names.
const DATA_KEYS: &[&str] = &[
    "imu.calib_file",
    "control.k_prop_file",
    "control.k_int_file",
    "control.lqr_q_file",
    "control.lqr_r_file",
];

/// File names a data key may be given: the shipped files, and the odd ones `config_dir` adds.
const DATA_NAMES: &[&str] = &[
    "imu_calib.txt",
    "K_prop.txt",
    "K_int.txt",
    "K_prop_full_ppzt.txt",
    "K_int_full_ppzt.txt",
    "K_prop_lqr_xyzt.txt",
    "K_int_lqr_xyzt.txt",
    "lqr-Q.txt",
    "lqr-Q-uquad.txt",
    "lqr-R.txt",
    "empty.txt",
    "few.txt",
    "zeros.txt",
    "huge.txt",
    "tiny.txt",
    "negative.txt",
    "malformed.txt",
    "nonfinite.txt",
    "a-folder",
    "missing.txt",
    "",
    ".",
    "/",
    "/dev/null",
    "../",
];

const CONFIG_WORDS: &[&str] = &[
    "gpsd",
    "off",
    "fake-zero",
    "fake-random",
    "x,y,z,theta",
    "psi,phi,z,theta",
    "psi,phi,z",
    "x,y,z",
    "",
    "127.0.0.1:2947",
    ":",
    "/dev/ttyS1",
    "/dev/i2c-2",
    "console.sock",
];

/// TOML values of every kind, and the numbers at the edges of the keys' types and ranges.
fn odd_toml() -> impl Strategy<Value = Toml> {
    let leaf = prop_oneof![
        2 => select(vec![
            0i64, 1, -1, 2, 3, 4, 6, 8, 12, 20, 100, 127, 128, 255, 256, -32769, 65536,
            i64::from(u32::MAX), i64::from(u32::MAX) + 1, i64::from(i32::MIN) - 1,
            1 << 53, i64::MAX, i64::MIN,
        ])
        .prop_map(Toml::Integer),
        1 => any::<i64>().prop_map(Toml::Integer),
        1 => (0i64..100_000).prop_map(Toml::Integer),
        2 => select(vec![
            f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.0, 0.0, 1e308, -1e308, 5e-324,
            1e-9, 0.01, 0.5, 1.0, 2.3, 2.3000000001, 10.0, 86_400.0, 86_400.1, 368.0, 368.1,
            1e17, -1.0,
        ])
        .prop_map(Toml::Float),
        1 => any::<f64>().prop_map(Toml::Float),
        1 => (-10.0..1000.0f64).prop_map(Toml::Float),
        2 => select(CONFIG_WORDS).prop_map(|s| Toml::String(s.to_string())),
        1 => select(DATA_NAMES).prop_map(|s| Toml::String(s.to_string())),
        1 => vec(any::<char>(), 0..8).prop_map(|c| Toml::String(c.into_iter().collect())),
        1 => any::<bool>().prop_map(Toml::Boolean),
    ];
    leaf.prop_recursive(2, 20, 16, |inner| {
        prop_oneof![
            vec(inner.clone(), 0..17).prop_map(Toml::Array),
            vec((select(vec!["a", "mass_kg", "step_max", "z"]), inner), 0..3).prop_map(|kv| {
                Toml::Table(kv.into_iter().map(|(k, v)| (k.to_string(), v)).collect())
            }),
        ]
    })
}

/// An edit of a profile's table, its paths picked by index from the known keys.
#[derive(Debug, Clone)]
enum ConfigEdit {
    Set(Index, Toml),
    SetElement(Index, Index, Toml),
    Remove(Index),
    Unknown(Index, String, Toml),
    DataFile(&'static str, &'static str),
}

fn config_edit() -> impl Strategy<Value = ConfigEdit> {
    prop_oneof![
        6 => (any::<Index>(), odd_toml()).prop_map(|(i, v)| ConfigEdit::Set(i, v)),
        2 => (any::<Index>(), any::<Index>(), odd_toml())
            .prop_map(|(i, j, v)| ConfigEdit::SetElement(i, j, v)),
        2 => any::<Index>().prop_map(ConfigEdit::Remove),
        1 => (any::<Index>(), select(vec!["mass", "extra", "K_prop_file", "", " "]), odd_toml())
            .prop_map(|(i, k, v)| ConfigEdit::Unknown(i, k.to_string(), v)),
        2 => (select(DATA_KEYS), select(DATA_NAMES)).prop_map(|(k, n)| ConfigEdit::DataFile(k, n)),
    ]
}

/// Every dotted path of `t`: tables and values.
fn paths(t: &toml::Table, prefix: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
    for (k, v) in t {
        prefix.push(k.clone());
        out.push(prefix.clone());
        if let Toml::Table(inner) = v {
            paths(inner, prefix, out);
        }
        prefix.pop();
    }
}

/// The value at `path`, creating tables on the way (a value in the way becomes a table).
fn entry<'a>(t: &'a mut toml::Table, path: &[String]) -> &'a mut Toml {
    let (last, parents) = path.split_last().expect("paths are not empty");
    let mut cur = t;
    for p in parents {
        let v = cur
            .entry(p.clone())
            .or_insert_with(|| Toml::Table(toml::Table::new()));
        if !v.is_table() {
            *v = Toml::Table(toml::Table::new());
        }
        cur = v.as_table_mut().expect("made a table");
    }
    cur.entry(last.clone()).or_insert(Toml::Boolean(false))
}

fn apply_config_edit(t: &mut toml::Table, paths: &[Vec<String>], e: ConfigEdit) {
    match e {
        ConfigEdit::Set(i, v) => *entry(t, &paths[i.index(paths.len())]) = v,
        ConfigEdit::SetElement(i, j, v) => {
            if let Toml::Array(a) = entry(t, &paths[i.index(paths.len())])
                && !a.is_empty()
            {
                let k = j.index(a.len());
                a[k] = v;
            }
        }
        ConfigEdit::Remove(i) => {
            let path = &paths[i.index(paths.len())];
            let (last, parents) = path.split_last().expect("paths are not empty");
            let mut cur = &mut *t;
            for p in parents {
                match cur.get_mut(p).and_then(Toml::as_table_mut) {
                    Some(next) => cur = next,
                    None => return,
                }
            }
            cur.remove(last);
        }
        ConfigEdit::Unknown(i, key, v) => {
            let mut path = paths[i.index(paths.len())].clone();
            path.pop();
            path.push(key);
            *entry(t, &path) = v;
        }
        ConfigEdit::DataFile(key, name) => {
            let path: Vec<String> = key.split('.').map(str::to_string).collect();
            *entry(t, &path) = Toml::String(name.to_string());
        }
    }
}

/// A profile and its `--set` arguments.
#[derive(Clone)]
struct ConfigCase {
    text: String,
    sets: Vec<String>,
}

impl fmt::Debug for ConfigCase {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "--set arguments: {:?}", self.sets)?;
        writeln!(f, "profile ({} bytes):", self.text.len())?;
        f.write_str(&self.text)
    }
}

/// The shipped profiles, parsed, and every path in them.
struct Profiles {
    tables: Vec<toml::Table>,
    paths: Vec<Vec<String>>,
}

fn shipped_profiles() -> Profiles {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut tables = Vec::new();
    let mut all = Vec::new();
    for name in ["config/uquad.toml", "config/flight-2012-05.toml"] {
        let text = std::fs::read_to_string(root.join(name)).expect("a shipped profile");
        let t: toml::Table = toml::from_str(&text).expect("a shipped profile parses");
        paths(&t, &mut Vec::new(), &mut all);
        tables.push(t);
    }
    all.sort();
    all.dedup();
    Profiles { tables, paths: all }
}

/// A profile: a shipped one with values replaced, removed or added and its text cut or
/// spliced, or TOML-like soup; and `--set` arguments of known or odd keys and odd values.
fn config_case(p: Arc<Profiles>) -> impl Strategy<Value = ConfigCase> {
    const TOKENS: &[&str] = &[
        "[",
        "]",
        "[[",
        "]]",
        "=",
        "\"",
        "'",
        "\n",
        "\n[imu]\n",
        "\n[vehicle]\nmass_kg = 1.2\n",
        "mass_kg = ",
        "{",
        "}",
        ",",
        ".",
        "#",
        "nan",
        "inf",
        "1979-05-27T07:32:00Z",
        "\\u0000",
        "\"\"\"",
    ];
    let n_tables = p.tables.len();
    let q = p.clone();
    let key = prop_oneof![
        3 => any::<Index>().prop_map(move |i| q.paths[i.index(q.paths.len())].join(".")),
        1 => select(vec!["", ".", "a..b", " vehicle . mass_kg ", "vehicle.mass_kg.x", "=", "é"])
            .prop_map(str::to_string),
    ];
    let value = prop_oneof![
        odd_text(CONFIG_WORDS),
        odd_toml().prop_map(|v| v.to_string()),
        select(vec!["[1,2", "{a=", "\"open", "1 2", "=", "= 1", "'x'"]).prop_map(str::to_string),
    ];
    let set = (key, value, any::<bool>()).prop_map(|(k, v, eq)| {
        if eq {
            format!("{k}={v}")
        } else {
            format!("{k}{v}")
        }
    });
    let edited = (
        0..n_tables,
        vec(config_edit(), 0..5),
        prop_oneof![4 => Just(Vec::new()), 1 => vec(text_edit(TOKENS), 1..3)],
    )
        .prop_map(move |(base, edits, text_edits)| {
            let mut t = p.tables[base].clone();
            for e in edits {
                apply_config_edit(&mut t, &p.paths, e);
            }
            let mut text = toml::to_string(&t).unwrap_or_default();
            for e in &text_edits {
                apply_text_edit(&mut text, e);
            }
            text
        });
    let soup = vec(select(TOKENS).prop_union(select(CONFIG_WORDS)), 0..30).prop_map(|t| t.concat());
    (
        prop_oneof![6 => edited, 1 => soup],
        prop_oneof![3 => Just(Vec::new()), 1 => vec(set, 1..4)],
    )
        .prop_map(|(text, sets)| ConfigCase { text, sets })
}

/// A folder with copies of the shipped data files and odd ones beside them.
fn config_dir() -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("a temporary folder");
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
    for e in std::fs::read_dir(&shipped).expect("config/") {
        let p = e.expect("an entry").path();
        if p.extension().is_some_and(|x| x == "txt") {
            std::fs::copy(&p, dir.path().join(p.file_name().expect("a name"))).expect("copy");
        }
    }
    let many = |v: &str| vec![v; 300].join(" ");
    for (name, text) in [
        ("empty.txt", String::new()),
        ("few.txt", "1 2 3".to_string()),
        ("zeros.txt", many("0")),
        ("huge.txt", many("1.7976931348623157e308")),
        ("tiny.txt", many("5e-324")),
        ("negative.txt", many("-1e9")),
        ("malformed.txt", "1 2 x 4".to_string()),
        ("nonfinite.txt", format!("{} nan inf", many("1"))),
    ] {
        std::fs::write(dir.path().join(name), text).expect("write");
    }
    std::fs::create_dir(dir.path().join("a-folder")).expect("mkdir");
    dir
}

/// Every float of a configuration (to check none is NaN or infinite after validation).
fn floats(v: &Toml, path: &str, out: &mut Vec<(String, f64)>) {
    match v {
        Toml::Float(f) => out.push((path.to_string(), *f)),
        Toml::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, x)| floats(x, &format!("{path}[{i}]"), out)),
        Toml::Table(t) => t
            .iter()
            .for_each(|(k, x)| floats(x, &format!("{path}.{k}"), out)),
        _ => {}
    }
}

#[test]
fn config_loader() {
    let profiles = Arc::new(shipped_profiles());
    let dir = config_dir();
    let file: PathBuf = dir.path().join("profile.toml");
    let reloaded: PathBuf = dir.path().join("reloaded.toml");
    let tally = Tally::default();
    fuzz("config_loader", config_case(profiles), &tally, |case| {
        let mut sets = Vec::new();
        for s in &case.sets {
            let parsed = parse_set(s);
            tally.add(if parsed.is_ok() {
                "--set: parsed"
            } else {
                "--set: refused"
            });
            if let Ok((key, value)) = parsed {
                prop_assert!(!key.is_empty() && key.split('.').all(|p| !p.trim().is_empty()));
                prop_assert_eq!(
                    key.as_str(),
                    s.split_once('=').map_or("", |(k, _)| k.trim())
                );
                sets.push((key, value));
            }
        }
        std::fs::write(&file, &case.text).expect("write the profile");
        match load(&file, &sets) {
            Ok(profile) => {
                tally.add("profile: loaded");
                // What the modes build from a loaded profile.
                let _ = profile.motor_map();
                let _ = profile.controller();
                let _ = profile.estimator_core(false);
                let _ = profile.controller_core();
                let _ = profile.fake_positions().next_sample();
                // Validated: no NaN or infinity anywhere.
                let value = Toml::try_from(&profile.config).expect("a loaded profile serialises");
                let mut all = Vec::new();
                floats(&value, "", &mut all);
                for (key, f) in &all {
                    prop_assert!(f.is_finite(), "{} = {} was accepted", key, f);
                }
                // The run folder's config.toml: the resolved profile reloads to itself.
                let text = toml::to_string(&profile.config).expect("a loaded profile serialises");
                std::fs::write(&reloaded, &text).expect("write the reloaded profile");
                match load(&reloaded, &[]) {
                    Ok(again) => {
                        prop_assert_eq!(toml::to_string(&again.config).expect("serialises"), text)
                    }
                    Err(e) => prop_assert!(false, "the resolved profile is refused: {}", e),
                }
            }
            Err(e) => {
                tally.add(match e.problems.len() {
                    1 => "profile: 1 problem",
                    2..5 => "profile: 2-4 problems",
                    _ => "profile: 5+ problems",
                });
                prop_assert!(!e.problems.is_empty());
                let _ = e.to_string();
            }
        }
        Ok(())
    });
}

// ---------------------------------------------------------------------------------------------
// 5. The log readers
// ---------------------------------------------------------------------------------------------

use uquad::logs::{
    GpsLogRecord, ImuRawRecord, KalmanInRecord, LineError, Parsed, UQUAD_GPS_HEADER, fmt_time_us,
    parse_log, parse_time_and_4, parse_time_column, parse_time_column_pair, parse_time_us,
    parse_x_hat, push_fixed, records, write_gps_fix, write_values_row,
};

/// The first lines of each log of the 2012 flight (their `\n\r` line ends included), per log
/// in the order of [`log_line`]'s kinds.
fn flight_lines() -> Vec<Vec<String>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/flight-2012-05-25");
    let mut out = Vec::new();
    for name in [
        "imu_raw.log",
        "kalman_in.log",
        "x_hat.log",
        "w.log",
        "gps.log",
        "int.log",
    ] {
        let text = std::fs::read_to_string(dir.join(name)).expect("a 2012 log");
        out.push(
            text.split_inclusive('\n')
                .take(4)
                .map(str::to_string)
                .collect(),
        );
    }
    out
}

/// Floats as logs hold them, and the odd ones.
fn log_float() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -400.0..400.0f64,
        1 => select(vec![0.0, -0.0, 1e-9, 5e-9, 0.5e-8, 1e16, 1e17, -1e17, 1e300, 5e-324]),
        1 => any::<f64>(),
    ]
}

fn log_time() -> impl Strategy<Value = i64> {
    prop_oneof![
        4 => 0i64..100_000_000_000,
        1 => any::<i64>(),
        1 => select(vec![0, -1, i64::MAX, i64::MIN, i64::MIN + 1, 999_999, 1_000_000]),
    ]
}

/// Kinds of log line: imu_raw, kalman_in, x_hat, w/int, gps (gpsd fixes), gps (fake times).
const LOG_KINDS: usize = 6;

/// One valid line of a log of kind `kind`, as uquad writes it or from the 2012 flight.
fn log_line(kind: usize, seeds: &[Vec<String>]) -> BoxedStrategy<String> {
    let written = [
        (log_time(), log_time(), arb_frame())
            .prop_map(|(t_main_us, t_frame_us, frame)| {
                let mut s = String::new();
                ImuRawRecord {
                    t_main_us,
                    t_frame_us,
                    frame,
                }
                .write(&mut s);
                s
            })
            .boxed(),
        (log_time(), log_time(), vec(log_float(), 12))
            .prop_map(|(t_us, dt_us, v)| {
                let mut s = String::new();
                KalmanInRecord {
                    t_us,
                    dt_us,
                    t_frame_col: v[0],
                    acc_m_s2: [v[1], v[2], v[3]],
                    gyro_rad_s: [v[4], v[5], v[6]],
                    euler_rad: [v[7], v[8], v[9]],
                    temp_c: v[10],
                    alt_m: v[11],
                }
                .write(&mut s);
                s
            })
            .boxed(),
        vec(log_float(), 15)
            .prop_map(|v| {
                let mut s = String::new();
                write_values_row(&mut s, None, &v);
                s
            })
            .boxed(),
        (log_time(), vec(log_float(), 4))
            .prop_map(|(t, v)| {
                let mut s = String::new();
                write_values_row(&mut s, Some(t), &v);
                s
            })
            .boxed(),
        (log_time(), log_time(), any::<u8>(), vec(log_float(), 5))
            .prop_map(|(t, st, m, v)| {
                let mut s = String::new();
                write_gps_fix(&mut s, t, st, m, [v[0], v[1], v[2]], None, v[3], v[4]);
                s
            })
            .boxed(),
        prop_oneof![
            4 => log_time().prop_map(|t| format!("{}\t\n", fmt_time_us(t))),
            1 => Just(format!("{UQUAD_GPS_HEADER}\n")),
        ]
        .boxed(),
    ];
    let written = written.into_iter().nth(kind).expect("a log kind");
    match seeds.get(kind) {
        Some(lines) => prop_oneof![3 => written, 1 => select(lines.clone())].boxed(),
        None => written,
    }
}

/// An edit of one whitespace-separated field of a line.
#[derive(Debug, Clone)]
enum FieldEdit {
    Replace(Index, Index, String),
    Remove(Index, Index),
    Add(Index, String),
}

fn log_text() -> impl Strategy<Value = String> {
    const TOKENS: &[&str] = &[
        "\t", " ", "\n", "\r", "\n\r", "\r\n", "#", "-", ".", "e", "\u{b}", "\u{c}", "\u{85}",
        "\u{a0}",
    ];
    let seeds = flight_lines();
    let all: Vec<BoxedStrategy<String>> = (0..LOG_KINDS).map(|k| log_line(k, &seeds)).collect();
    // Mostly lines of one log, as files are; sometimes mixed.
    let lines = prop_oneof![
        4 => (0..LOG_KINDS).prop_flat_map(move |k| vec(log_line(k, &seeds), 0..6)),
        1 => vec(proptest::strategy::Union::new(all), 0..6),
    ];
    let field_edit = prop_oneof![
        3 => (any::<Index>(), any::<Index>(), odd_text(TOKENS))
            .prop_map(|(l, f, s)| FieldEdit::Replace(l, f, s)),
        1 => (any::<Index>(), any::<Index>()).prop_map(|(l, f)| FieldEdit::Remove(l, f)),
        1 => (any::<Index>(), odd_text(TOKENS)).prop_map(|(l, s)| FieldEdit::Add(l, s)),
    ];
    let edited = (
        lines,
        prop_oneof![2 => Just(Vec::new()), 1 => vec(field_edit, 1..4)],
        prop_oneof![2 => Just(Vec::new()), 1 => vec(text_edit(TOKENS), 1..3)],
    )
        .prop_map(|(mut lines, field_edits, text_edits)| {
            for e in field_edits {
                if lines.is_empty() {
                    break;
                }
                let at = |l: &Index| l.index(lines.len());
                let (k, f, with) = match e {
                    FieldEdit::Replace(l, f, s) => (at(&l), Some(f), Some(s)),
                    FieldEdit::Remove(l, f) => (at(&l), Some(f), None),
                    FieldEdit::Add(l, s) => (at(&l), None, Some(s)),
                };
                let mut fields: Vec<String> =
                    lines[k].split_whitespace().map(str::to_string).collect();
                match (f, with) {
                    (Some(f), Some(s)) if !fields.is_empty() => {
                        let j = f.index(fields.len());
                        fields[j] = s;
                    }
                    (Some(f), None) if !fields.is_empty() => {
                        let j = f.index(fields.len());
                        fields.remove(j);
                    }
                    (None, Some(s)) => fields.push(s),
                    _ => {}
                }
                lines[k] = fields.join("\t") + "\n";
            }
            let mut text = lines.concat();
            for e in &text_edits {
                apply_text_edit(&mut text, e);
            }
            text
        });
    let soup = vec(
        select(vec![
            '0', '1', '5', '9', '.', '-', '+', '\t', ' ', '\n', '\r', '#', 'e', 'n', 'a', 'i', 'f',
        ]),
        0..200,
    )
    .prop_map(|c| c.into_iter().collect::<String>());
    prop_oneof![6 => edited, 1 => soup, 1 => vec(any::<char>(), 0..100).prop_map(|c| c.into_iter().collect())]
}

/// What every log parse must give: the rows and a dropped last line account for every record;
/// an error names the line of a record.
fn check_parse<T>(
    tally: &Tally,
    log: &'static str,
    text: &str,
    result: &Result<Parsed<T>, LineError>,
) -> Result<(), TestCaseError> {
    let lines: Vec<usize> = records(text).map(|(l, _)| l).collect();
    if result.as_ref().is_ok_and(|p| !p.rows.is_empty()) {
        tally.add(log);
    }
    match result {
        Ok(p) => {
            prop_assert_eq!(
                p.rows.len() + usize::from(p.truncated.is_some()),
                lines.len()
            );
            if let Some(t) = &p.truncated {
                prop_assert_eq!(Some(&t.line), lines.last());
            }
        }
        Err(e) => prop_assert!(lines.contains(&e.line), "error at line {}", e.line),
    }
    Ok(())
}

fn same_f64(a: f64, b: f64) -> bool {
    a == b || (a.is_nan() && b.is_nan())
}

#[test]
fn log_readers() {
    let strategy = (log_text(), any::<f64>(), 0u32..18, log_time());
    let tally = Tally::default();
    fuzz("log_readers", strategy, &tally, |(text, v, decimals, t)| {
        // imu_raw.log: a row prints back to a line that reads as the same row.
        let imu = parse_log(&text, ImuRawRecord::parse_fields);
        check_parse(&tally, "imu_raw rows", &text, &imu)?;
        for r in imu.iter().flat_map(|p| &p.rows) {
            let mut line = String::new();
            r.write(&mut line);
            let f: Vec<&str> = line.split_ascii_whitespace().collect();
            prop_assert_eq!(ImuRawRecord::parse_fields(&f), Ok(*r));
        }
        // kalman_in.log: printing a row is stable after one read.
        let kalman = parse_log(&text, KalmanInRecord::parse_fields);
        check_parse(&tally, "kalman_in rows", &text, &kalman)?;
        for r in kalman.iter().flat_map(|p| &p.rows) {
            let mut once = String::new();
            r.write(&mut once);
            let f: Vec<&str> = once.split_ascii_whitespace().collect();
            let again = KalmanInRecord::parse_fields(&f);
            prop_assert!(again.is_ok(), "{:?} from {:?}", again, once);
            let mut twice = String::new();
            again.iter().for_each(|a| a.write(&mut twice));
            prop_assert_eq!(&once, &twice);
        }
        // x_hat.log, w.log and int.log.
        let x_hat = parse_log(&text, parse_x_hat);
        check_parse(&tally, "x_hat rows", &text, &x_hat)?;
        for r in x_hat.iter().flat_map(|p| &p.rows) {
            let mut once = String::new();
            write_values_row(&mut once, None, r);
            let f: Vec<&str> = once.split_ascii_whitespace().collect();
            let again = parse_x_hat(&f);
            prop_assert!(again.is_ok(), "{:?} from {:?}", again, once);
        }
        let four = parse_log(&text, parse_time_and_4);
        check_parse(&tally, "w/int rows", &text, &four)?;
        for (t_us, r) in four.iter().flat_map(|p| &p.rows) {
            let mut once = String::new();
            write_values_row(&mut once, Some(*t_us), r);
            let f: Vec<&str> = once.split_ascii_whitespace().collect();
            let again = parse_time_and_4(&f);
            prop_assert!(
                again.as_ref().is_ok_and(|(t, _)| t == t_us),
                "{:?} from {:?}",
                again,
                once
            );
        }
        // gps.log: uquad's lines round-trip exactly.
        let gps = parse_log(&text, GpsLogRecord::parse_fields);
        check_parse(&tally, "gps rows", &text, &gps)?;
        for r in gps.iter().flat_map(|p| &p.rows) {
            if let GpsLogRecord::Gpsd {
                t_us,
                fix_mode,
                pos_m,
                vel_m_s,
                lat_deg,
                lon_deg,
                ..
            } = *r
                && let Ok(mode) = u8::try_from(fix_mode)
            {
                let mut line = String::new();
                write_gps_fix(&mut line, t_us, 0, mode, pos_m, vel_m_s, lat_deg, lon_deg);
                let f: Vec<&str> = line.split_ascii_whitespace().collect();
                let again = GpsLogRecord::parse_fields(&f);
                let same = match again {
                    Ok(GpsLogRecord::Gpsd {
                        t_us: t2,
                        fix_mode: m2,
                        pos_m: p2,
                        vel_m_s: v2,
                        lat_deg: la2,
                        lon_deg: lo2,
                        alt_m,
                    }) => {
                        t2 == t_us
                            && m2 == fix_mode
                            && (0..3).all(|i| same_f64(p2[i], pos_m[i]))
                            && match (v2, vel_m_s) {
                                (Some(a), Some(b)) => (0..3).all(|i| same_f64(a[i], b[i])),
                                (a, b) => a.is_none() && b.is_none(),
                            }
                            && same_f64(la2, lat_deg)
                            && same_f64(lo2, lon_deg)
                            && same_f64(alt_m, pos_m[2])
                    }
                    _ => false,
                };
                prop_assert!(same, "{:?} from {:?}", again, line);
            }
        }
        check_parse(
            &tally,
            "time rows",
            &text,
            &parse_log(&text, parse_time_column),
        )?;
        check_parse(
            &tally,
            "time pair rows",
            &text,
            &parse_log(&text, parse_time_column_pair),
        )?;

        // Times: any field that reads as a time prints back to the same time; every time but
        // i64::MIN (which no text reads as) prints to a text that reads back.
        for field in text.split_ascii_whitespace() {
            if let Some(t) = parse_time_us(field) {
                prop_assert_eq!(parse_time_us(&fmt_time_us(t)), Some(t));
            }
        }
        if t != i64::MIN {
            prop_assert_eq!(parse_time_us(&fmt_time_us(t)), Some(t));
        }
        // The fixed-point printer equals the standard formatter (C's %.Nf) for any value.
        let mut ours = String::new();
        push_fixed(&mut ours, v, decimals);
        prop_assert_eq!(ours, format!("{v:.*}", decimals as usize));
        Ok(())
    });
}

// ---------------------------------------------------------------------------------------------
// mavlink_frames: the ground-station link's framing and what it does with a message
// ---------------------------------------------------------------------------------------------

/// A message a ground station sends, from generated numbers.
fn gcs_message(kind: u8, f: [f32; 7], id: u8) -> mavlink::dialects::common::MavMessage {
    use mavlink::dialects::common::*;
    let cmd = [
        MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
        MavCmd::MAV_CMD_NAV_TAKEOFF,
        MavCmd::MAV_CMD_DO_SET_MODE,
        MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
        MavCmd::MAV_CMD_REQUEST_MESSAGE,
    ][usize::from(id % 5)];
    let param_id = uquad::gcs::params::TABLE[usize::from(id) % uquad::gcs::params::TABLE.len()].0;
    match kind % 4 {
        0 => MavMessage::HEARTBEAT(HEARTBEAT_DATA::DEFAULT),
        1 => MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            param1: f[0],
            param2: f[1],
            param7: f[6],
            command: cmd,
            ..COMMAND_LONG_DATA::DEFAULT
        }),
        2 => MavMessage::PARAM_SET(PARAM_SET_DATA {
            param_value: f[2],
            param_id: param_id.into(),
            ..PARAM_SET_DATA::DEFAULT
        }),
        _ => MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
            param_index: -1,
            param_id: param_id.into(),
            ..PARAM_REQUEST_READ_DATA::DEFAULT
        }),
    }
}

/// Any float, the odd ones often.
fn odd_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        select(vec![
            0.0,
            1.0,
            -1.0,
            f32::NAN,
            f32::INFINITY,
            21196.0,
            1e30,
            0.4
        ]),
        any::<f32>()
    ]
}

#[test]
fn mavlink_frames() {
    use uquad::gcs::wire::{Decoder, Encoder};
    let message = (any::<u8>(), std::array::from_fn(|_| odd_f32()), any::<u8>());
    let strategy = (
        vec(message, 1..6),
        vec(byte_edit(), 0..4),
        vec(any::<Index>(), 0..4),
    );
    let tally = Tally::default();
    fuzz(
        "mavlink_frames",
        strategy,
        &tally,
        |(msgs, edits, splits)| {
            let mut enc = Encoder::new(255, 190);
            let mut bytes = Vec::new();
            for (kind, f, id) in &msgs {
                enc.encode(&gcs_message(*kind, *f, *id), &mut bytes);
            }
            let clean = bytes.clone();
            for e in &edits {
                apply_byte_edit(&mut bytes, e);
            }
            // As one datagram, and as a stream cut anywhere: no panic; untouched bytes give back
            // every message.
            let mut d = Decoder::for_datagrams();
            d.push(&bytes);
            let mut got = Vec::new();
            while let Some(m) = d.next_message() {
                got.push(m);
            }
            let mut s = Decoder::for_stream();
            let mut cuts: Vec<usize> = splits.iter().map(|i| i.index(bytes.len() + 1)).collect();
            cuts.sort_unstable();
            let mut from = 0;
            for cut in cuts.into_iter().chain([bytes.len()]) {
                s.push(&bytes[from..cut]);
                from = cut;
                while s.next_message().is_some() {}
            }
            if bytes == clean {
                prop_assert_eq!(got.len(), msgs.len());
                prop_assert_eq!(s.counts.frames as usize, msgs.len());
                tally.add("clean");
            } else {
                tally.add(if got.is_empty() {
                    "edited, none"
                } else {
                    "edited, some"
                });
            }
            // What the link does with each message: map a command, convert a parameter's value.
            let params = uquad::gcs::params::Params::of(&uquad::config::Config::default());
            for r in got {
                use mavlink::dialects::common::MavMessage;
                match r.msg {
                    MavMessage::COMMAND_LONG(c) => {
                        let p = [
                            c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7,
                        ];
                        let args = uquad::gcs::commands::Args { p, frame: None };
                        let _ = uquad::gcs::commands::map(c.command, args);
                    }
                    MavMessage::PARAM_SET(p) => {
                        let id = p.param_id.to_str().unwrap_or("");
                        if let Some(param) = params.find(id).and_then(|i| params.get(i)) {
                            let _ = param.toml_value(p.param_value);
                        }
                    }
                    _ => {}
                }
            }
            Ok(())
        },
    );
}

// ---------------------------------------------------------------------------------------------
// 7. RC receiver frames (SBUS, CRSF)
// ---------------------------------------------------------------------------------------------

use uquad::core::rc::{LinkStats, RcEvent, RcFrame, TICKS_MAX, crsf, sbus};

/// Bytes that matter to SBUS and CRSF: headers, addresses, lengths, types, end bytes.
fn rc_byte() -> impl Strategy<Value = u8> {
    prop_oneof![
        select(vec![
            0x0f, 0x00, 0x04, 0x14, 0x16, 0x18, 0x0c, 0xc8, 0xee, 0xea, 0xec, 0xff, 62, 63, 1, 2
        ]),
        any::<u8>()
    ]
}

fn rc_frame() -> impl Strategy<Value = RcFrame> {
    (any::<[u16; 16]>(), any::<bool>(), any::<bool>()).prop_map(|(ch, lost, failsafe)| RcFrame {
        channels: ch.map(|c| c & TICKS_MAX),
        frame_lost: lost,
        failsafe,
    })
}

/// A stream of one protocol's frames (channels and, for CRSF, link statistics) with noise
/// before and edits after, or random bytes.
fn rc_stream(crsf_frames: bool) -> impl Strategy<Value = Hex> {
    prop_oneof![
        vec(any::<u8>(), 0..300),
        vec(rc_byte(), 0..300),
        (
            vec((rc_frame(), any::<(i16, u8, i8)>()), 1..6),
            vec(rc_byte(), 0..8),
            vec(byte_edit(), 0..6)
        )
            .prop_map(move |(frames, lead, edits)| {
                let mut b = lead;
                for (f, (rssi, lq, snr)) in &frames {
                    if crsf_frames {
                        b.extend(crsf::encode_channels(&f.channels));
                        let link = LinkStats {
                            rssi_dbm: *rssi,
                            link_quality_pct: *lq,
                            snr_db: *snr,
                        };
                        b.extend(crsf::encode_link(&link));
                    } else {
                        b.extend(sbus::encode(f));
                    }
                }
                for e in &edits {
                    apply_byte_edit(&mut b, e);
                }
                b
            }),
    ]
    .prop_map(Hex)
}

/// Feeds `bytes` to a fresh decoder of either protocol in `chunks` (cycled), checking that
/// less than a frame stays buffered and the counts match what came out.
fn rc_decode(
    bytes: &[u8],
    chunks: &[usize],
    crsf_frames: bool,
) -> Result<Vec<RcEvent>, TestCaseError> {
    use uquad::core::rc::Decoder;
    let mut d = if crsf_frames {
        Decoder::Crsf(crsf::CrsfDecoder::new())
    } else {
        Decoder::Sbus(sbus::SbusDecoder::new())
    };
    let max = if crsf_frames {
        crsf::FRAME_MAX
    } else {
        sbus::FRAME_LEN
    };
    let mut out = Vec::new();
    let (mut fed, mut k) = (0usize, 0usize);
    while fed < bytes.len() {
        let n = chunks[k % chunks.len()].clamp(1, bytes.len() - fed);
        d.feed(&bytes[fed..fed + n], &mut out);
        fed += n;
        k += 1;
        let buffered = match &d {
            Decoder::Sbus(s) => s.buffered(),
            Decoder::Crsf(c) => c.buffered(),
        };
        prop_assert!(buffered < max, "{buffered} bytes buffered");
        let s = d.stats();
        let channels = out
            .iter()
            .filter(|e| matches!(e, RcEvent::Channels(_)))
            .count();
        prop_assert_eq!(s.frames as usize, channels);
        prop_assert!(s.discarded_bytes as usize <= fed);
    }
    for e in &out {
        if let RcEvent::Channels(f) = e {
            prop_assert!(f.channels.iter().all(|&c| c <= TICKS_MAX));
        }
    }
    Ok(out)
}

#[test]
fn rc_frames() {
    let strategy = (
        any::<bool>(),
        any::<bool>().prop_flat_map(rc_stream).prop_map(|h| h.0),
        vec(1usize..40, 1..6),
        any::<[u8; sbus::FRAME_LEN]>(),
        rc_frame(),
    );
    let tally = Tally::default();
    fuzz(
        "rc_frames",
        strategy,
        &tally,
        |(crsf_frames, bytes, chunks, candidate, frame)| {
            // However the stream is split, the same frames.
            let split = rc_decode(&bytes, &chunks, crsf_frames)?;
            let whole = rc_decode(&bytes, &[bytes.len().max(1)], crsf_frames)?;
            prop_assert_eq!(&split, &whole);
            tally.add(match (crsf_frames, split.is_empty()) {
                (false, true) => "sbus: nothing",
                (false, false) => "sbus: frames",
                (true, true) => "crsf: nothing",
                (true, false) => "crsf: frames",
            });
            // An SBUS candidate parses exactly when its header and end byte are right.
            let mut c = candidate;
            if c[1] % 2 == 0 {
                c[0] = sbus::HEADER;
                c[sbus::FRAME_LEN - 1] = 0;
            }
            let framed = c[0] == sbus::HEADER && [0, 4, 0x14, 0x24, 0x34].contains(&c[24]);
            prop_assert_eq!(sbus::parse(&c).is_some(), framed);
            // Each protocol's frame decodes to what was encoded.
            prop_assert_eq!(sbus::parse(&sbus::encode(&frame)), Some(frame));
            let mut d = crsf::CrsfDecoder::new();
            let mut out = Vec::new();
            d.feed(&crsf::encode_channels(&frame.channels), &mut out);
            let plain = RcFrame {
                frame_lost: false,
                failsafe: false,
                ..frame
            };
            prop_assert_eq!(out, vec![RcEvent::Channels(plain)]);
            Ok(())
        },
    );
}
