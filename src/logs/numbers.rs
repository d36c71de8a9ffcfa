//! Exact, fast printing of the logs' numbers: `%.Nf` decimals, the original's `%ld.%06ld`
//! times, plain integers and the shortest `{:e}` form of innov.log's ratios. Logs print tens
//! of thousands of numbers per run and the generic formatter dominated replay time; these
//! print through a stack buffer (decimals eight digits at a time), copied into the line once.

use std::fmt::Write as _;

/// "00", "01", … "99".
const DIGIT_PAIRS: &[u8; 200] = b"0001020304050607080910111213141516171819\
2021222324252627282930313233343536373839\
4041424344454647484950515253545556575859\
6061626364656667686970717273747576777879\
8081828384858687888990919293949596979899";

/// 10⁰ … 10¹⁵.
const POW10: [u64; 16] = {
    let mut p = [1u64; 16];
    let mut k = 1;
    while k < 16 {
        p[k] = p[k - 1] * 10;
        k += 1;
    }
    p
};

/// Room for a sign, 20 integer digits, a point and 15 decimals.
const BUF_LEN: usize = 40;

/// Writes the two digits of `v` < 100 just before `pos`; returns where they start.
fn put_pair(buf: &mut [u8; BUF_LEN], pos: usize, v: u32) -> usize {
    let pair = v as usize * 2;
    buf[pos - 2..pos].copy_from_slice(&DIGIT_PAIRS[pair..pair + 2]);
    pos - 2
}

/// The eight decimal digits of `v` < 10⁸, zero-padded, as ASCII: all of them at once in one
/// 64-bit word (two 4-digit halves, then four 2-digit quarters, then eight digits, each split
/// by a multiply and shift exact in that range), a few instructions where a digit at a time
/// took a division each.
fn eight_digits(v: u32) -> [u8; 8] {
    debug_assert!(v < 100_000_000);
    let v = u64::from(v);
    // Lanes of 32 bits: abcd, efgh.
    let halves = (v / 10_000) | ((v % 10_000) << 32);
    // x / 100 = (x · 10486) >> 20 for x < 10⁴: lanes of 16 bits ab, cd, ef, gh.
    let hundreds = ((halves * 10_486) >> 20) & 0x0000_007F_0000_007F;
    let quarters = hundreds | ((halves - hundreds * 100) << 16);
    // x / 10 = (x · 103) >> 10 for x < 100: lanes of 8 bits a … h.
    let tens = ((quarters * 103) >> 10) & 0x000F_000F_000F_000F;
    let digits = tens | ((quarters - tens * 10) << 8);
    (digits + 0x3030_3030_3030_3030).to_le_bytes()
}

/// Writes the digits of `v` (no padding) just before `pos`; returns where they start.
fn put_u64(buf: &mut [u8; BUF_LEN], mut pos: usize, mut v: u64) -> usize {
    while v >= 100 {
        pos = put_pair(buf, pos, (v % 100) as u32);
        v /= 100;
    }
    if v >= 10 {
        put_pair(buf, pos, v as u32)
    } else {
        buf[pos - 1] = b'0' + v as u8;
        pos - 1
    }
}

/// Appends `[-]int.frac`, `frac` < 10^decimals zero-padded to `decimals` (≤ 15) digits (no
/// point when 0).
fn push_parts(out: &mut String, negative: bool, int_part: u64, frac: u64, decimals: usize) {
    let mut buf = [0u8; BUF_LEN];
    let mut pos = BUF_LEN;
    if decimals > 0 {
        // The sixteen digits of `frac`, of which the last `decimals` are printed.
        buf[BUF_LEN - 8..].copy_from_slice(&eight_digits((frac % 100_000_000) as u32));
        if decimals > 8 {
            // `% 10⁸` keeps eight_digits' range (and its ASCII) whatever the caller passed.
            let high = eight_digits(((frac / 100_000_000) % 100_000_000) as u32);
            buf[BUF_LEN - 16..BUF_LEN - 8].copy_from_slice(&high);
        }
        pos -= decimals + 1;
        buf[pos] = b'.';
    }
    pos = put_u64(&mut buf, pos, int_part);
    if negative {
        pos -= 1;
        buf[pos] = b'-';
    }
    // SAFETY: only ASCII digits, '.' and '-' were written, so the String stays UTF-8 (checking
    // it again cost as much as the printing).
    unsafe { out.as_mut_vec() }.extend_from_slice(&buf[pos..]);
}

/// Appends `v` as Rust's `{:e}` prints it (the shortest digits that read back as `v`, e.g.
/// `1.5e-7`, `3e0`, `-0e0`) for finite `v`, from the shortest digits [`zmij`] finds (the same
/// digits; its own layout differs), at a fifth of the standard formatter's cost.
pub fn push_shortest_exp(out: &mut String, v: f64) {
    if !v.is_finite() || may_tie(v.abs()) {
        let _ = write!(out, "{v:e}");
        return;
    }
    if v.is_sign_negative() {
        out.push('-');
    }
    if v == 0.0 {
        out.push_str("0e0");
        return;
    }
    let mut digits = [0u8; DIGITS_LEN];
    let (len, sci_exp) = shortest_digits(v.abs(), &mut digits);
    // d.ddd then e and the exponent, laid out in one buffer and copied once.
    let mut text = [0u8; DIGITS_LEN + 2];
    text[0] = digits[0];
    let mut end = 1;
    if len > 1 {
        text[1] = b'.';
        text[2..len + 1].copy_from_slice(&digits[1..len]);
        end = len + 1;
    }
    text[end] = b'e';
    // SAFETY: zmij prints ASCII digits only, so the String stays UTF-8.
    unsafe { out.as_mut_vec() }.extend_from_slice(&text[..end + 1]);
    push_parts(out, sci_exp < 0, u64::from(sci_exp.unsigned_abs()), 0, 0);
}

/// Room for a shortest form's significant digits (zmij prints at most 17, in at most 24 bytes).
const DIGITS_LEN: usize = 40;

/// The shortest significant digits of `a` > 0 (finite) into `digits`, without trailing zeros:
/// how many, and the power of ten of the first. zmij lays them out in fixed or exponent
/// notation by magnitude ("0.001234", "12.34", "1.234e33"); read back from either.
fn shortest_digits(a: f64, digits: &mut [u8; DIGITS_LEN]) -> (usize, i32) {
    let mut buffer = zmij::Buffer::new();
    let printed = buffer.format_finite(a).as_bytes();
    let (mantissa, exp) = match printed.iter().rposition(|&b| b == b'e') {
        Some(e) => (&printed[..e], parse_exp(&printed[e + 1..])),
        None => (printed, 0),
    };
    let (whole, fraction) = match mantissa.iter().position(|&b| b == b'.') {
        Some(p) => (&mantissa[..p], &mantissa[p + 1..]),
        None => (mantissa, &[][..]),
    };
    let (significant, sci_exp): (&[u8], i32) = if whole == b"0" {
        let zeros = fraction.iter().take_while(|&&b| b == b'0').count();
        (&fraction[zeros..], exp - 1 - zeros as i32)
    } else {
        (whole, exp + whole.len() as i32 - 1)
    };
    let mut len = 0;
    let rest = if whole == b"0" { &[][..] } else { fraction };
    for (d, &b) in digits.iter_mut().zip(significant.iter().chain(rest)) {
        *d = b;
        len += 1;
    }
    let len = digits[..len]
        .iter()
        .rposition(|&b| b != b'0')
        .map_or(1, |k| k + 1);
    (len, sci_exp)
}

/// Whether the shortest digits of `a` ≥ 0 could be a choice between two equally short and
/// equally close candidates (or one on the edge of what reads back as `a`), where two correct
/// algorithms may differ. That needs `a` ≥ 2⁵², or `a`'s exact decimal expansion to end within
/// 18 significant digits (m·2⁻ᵏ with m odd is m·5ᵏ·10⁻ᵏ): `1 + 2⁻¹⁷` is one. The standard
/// formatter prints those.
fn may_tie(a: f64) -> bool {
    if a >= 4_503_599_627_370_496.0 {
        return true;
    }
    let (mantissa, exp) = binary_parts(a);
    if mantissa == 0 {
        return false;
    }
    let zeros = mantissa.trailing_zeros() as i32;
    // a = odd · 2^−k; k ≤ 0 is an integer below 2⁵², printed exactly.
    let k = -(exp + zeros);
    k > 0
        && k <= 26
        && u128::from(mantissa >> zeros) * 5u128.pow(k as u32) < 1_000_000_000_000_000_000
}

/// A finite `v` ≥ 0 as mantissa · 2^exp, exactly (subnormals included).
fn binary_parts(v: f64) -> (u64, i32) {
    let bits = v.to_bits();
    let biased_exp = ((bits >> 52) & 0x7ff) as i32;
    let fraction = bits & ((1u64 << 52) - 1);
    if biased_exp == 0 {
        (fraction, -1074)
    } else {
        (fraction | (1u64 << 52), biased_exp - 1075)
    }
}

/// A printed exponent: optional sign and digits.
fn parse_exp(text: &[u8]) -> i32 {
    let (negative, digits) = match text.split_first() {
        Some((b'-', rest)) => (true, rest),
        Some((b'+', rest)) => (false, rest),
        _ => (false, text),
    };
    let magnitude = digits
        .iter()
        .filter(|d| d.is_ascii_digit())
        .fold(0i32, |e, &d| e * 10 + i32::from(d - b'0'));
    if negative { -magnitude } else { magnitude }
}

/// Appends `v`'s decimal digits.
pub fn push_u64(out: &mut String, v: u64) {
    push_parts(out, false, v, 0, 0);
}

/// Appends a time in µs as the original's `%ld.%06ld` seconds.
pub fn push_time_us(out: &mut String, t_us: i64) {
    let a = t_us.unsigned_abs();
    push_parts(out, t_us < 0, a / 1_000_000, a % 1_000_000, 6);
}

/// Appends `v` with exactly `decimals` digits after the point, as C's `%.Nf` prints it: the
/// exact binary value rounded half to even. Falls back to the standard formatter outside its
/// range (non-finite, |v| ≥ 1e17, > 15 digits).
pub fn push_fixed(out: &mut String, v: f64, decimals: u32) {
    if !v.is_finite() || v.abs() >= 1e17 || decimals > 15 {
        let _ = write!(out, "{v:.*}", decimals as usize);
        return;
    }
    let a = v.abs();
    // Both parts are exact: a < 1e17 < 2⁶³ truncates exactly through u64, and a − trunc(a) is
    // exact.
    let mut int_part = a as u64;
    let frac = a - int_part as f64;
    let pow10 = POW10[decimals as usize];
    let mut frac_units = 0u64;
    if frac > 0.0 {
        frac_units = round_scaled(frac, pow10, decimals == 0 && int_part & 1 == 1);
        if frac_units == pow10 {
            int_part += 1;
            frac_units = 0;
        }
    }
    push_parts(
        out,
        v.is_sign_negative(),
        int_part,
        frac_units,
        decimals as usize,
    );
}

/// frac·pow10 rounded half to even, for 0 < frac < 1 exactly: frac = mantissa·2^exp with
/// exp < 0, and mantissa·pow10 < 2¹⁰³ fits in u128. On a tie the parity is the last printed
/// digit's: `int_odd` (the integer part's) when no decimals are printed.
fn round_scaled(frac: f64, pow10: u64, int_odd: bool) -> u64 {
    let (mantissa, exp) = binary_parts(frac);
    let scaled = u128::from(mantissa) * u128::from(pow10);
    let shift = exp.unsigned_abs();
    if shift >= 120 {
        // scaled < 2¹⁰³ is below half a unit: rounds to 0.
        return 0;
    }
    let q = (scaled >> shift) as u64;
    let rem = scaled & ((1u128 << shift) - 1);
    let half = 1u128 << (shift - 1);
    let odd = if pow10 == 1 { int_odd } else { q & 1 == 1 };
    if rem > half || (rem == half && odd) {
        q + 1
    } else {
        q
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eight_digits_of_every_kind_of_value() {
        let mut x = 0x9e37_79b9u32;
        let mut values = vec![0, 1, 9, 10, 99, 100, 9_999, 10_000, 10_001, 99_999_999];
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            values.push(x % 100_000_000);
        }
        for v in values {
            assert_eq!(eight_digits(v), *format!("{v:08}").as_bytes(), "{v}");
        }
    }

    #[test]
    fn shortest_exp_prints_as_the_standard_formatter() {
        let mut values = vec![
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.1,
            1.5e-7,
            123.456,
            1e22,
            1e23,
            5e-324,
            f64::MAX,
            f64::MIN_POSITIVE,
            4.0e-8,
            1.0 / 3.0,
            f64::from_bits(0x44b5_2d02_c7e1_4af5),
            1.0 + 2f64.powi(-17),
            0.5 + 2f64.powi(-30),
            -1_149_636_667_324_797.3,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        let mut x = 0x2545_f491_4f6c_dd1du64;
        for _ in 0..200_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            values.push(f64::from_bits(x));
            // Test ratios: mostly between 1e-6 and 1e3.
            values.push((x >> 11) as f64 / (1u64 << 53) as f64 * 10f64.powi((x % 10) as i32 - 6));
            // Few significant bits: where ties live.
            values.push((x >> 40) as f64 * 2f64.powi((x % 64) as i32 - 40));
        }
        // Every power of two: uneven rounding intervals, rarely drawn at random.
        values.extend((-1074..=1023i64).map(|k| match k {
            -1022.. => f64::from_bits(((k + 1023) as u64) << 52),
            _ => f64::from_bits(1 << (k + 1074)),
        }));
        for v in values.into_iter().filter(|v| !v.is_nan()) {
            let mut ours = String::new();
            push_shortest_exp(&mut ours, v);
            assert_eq!(ours, format!("{v:e}"), "{v:?}");
        }
    }

    #[test]
    fn integers_and_times_print_as_c_does() {
        for v in [0u64, 7, 10, 99, 100, 12345, u64::MAX] {
            let mut s = String::new();
            push_u64(&mut s, v);
            assert_eq!(s, v.to_string());
        }
        for (t, text) in [
            (12_126_526i64, "12.126526"),
            (5, "0.000005"),
            (-1_500_000, "-1.500000"),
            (0, "0.000000"),
        ] {
            let mut s = String::new();
            push_time_us(&mut s, t);
            assert_eq!(s, text);
        }
    }
}
