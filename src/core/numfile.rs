//! Whitespace-separated number files: `imu_calib.txt` (spec 2.1) and the gain and weight
//! matrices (spec 4.3). The original read them with `fscanf("%lf")`, in order, row-major.
//!
//! Parsing is pure (text in, numbers out) so the caller owns the file I/O and can name the file
//! in its error messages.

/// A malformed or missing number, located for the user.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NumberError {
    #[error("number {index} (line {line}, column {column}) is malformed: {text:?}")]
    Malformed {
        /// 1-based position of the number in the file.
        index: usize,
        line: usize,
        column: usize,
        text: String,
    },
    #[error("expected {expected} numbers, found {found}")]
    TooFew { expected: usize, found: usize },
    #[error("number {index} (line {line}, column {column}) is not finite: {text:?}")]
    NotFinite {
        index: usize,
        line: usize,
        column: usize,
        text: String,
    },
}

/// Reads every whitespace-separated number of `text`, reporting the first malformed one.
pub fn parse_numbers(text: &str) -> Result<Vec<f64>, NumberError> {
    let mut out = Vec::new();
    for (line_no, line) in text.lines().enumerate() {
        let mut rest = line;
        let mut offset = 0usize;
        while let Some(start) = rest.find(|c: char| !c.is_whitespace()) {
            let token_and_after = &rest[start..];
            let len = token_and_after
                .find(char::is_whitespace)
                .unwrap_or(token_and_after.len());
            let token = &token_and_after[..len];
            let column = offset + start + 1;
            let index = out.len() + 1;
            let value: f64 = token.parse().map_err(|_| NumberError::Malformed {
                index,
                line: line_no + 1,
                column,
                text: token.to_string(),
            })?;
            if !value.is_finite() {
                return Err(NumberError::NotFinite {
                    index,
                    line: line_no + 1,
                    column,
                    text: token.to_string(),
                });
            }
            out.push(value);
            offset += start + len;
            rest = &token_and_after[len..];
        }
    }
    Ok(out)
}

/// Reads exactly the first `count` numbers, as the original's `uquad_mat_load` did: a file with
/// more numbers is accepted (the rest is ignored), one with fewer is refused.
pub fn parse_exact(text: &str, count: usize) -> Result<Vec<f64>, NumberError> {
    let mut numbers = parse_numbers(text)?;
    if numbers.len() < count {
        return Err(NumberError::TooFew {
            expected: count,
            found: numbers.len(),
        });
    }
    numbers.truncate(count);
    Ok(numbers)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_numbers_with_positions() {
        assert_eq!(
            parse_numbers(" 1 -2.5e-3\n\t4\n").unwrap(),
            vec![1.0, -2.5e-3, 4.0]
        );
        let err = parse_numbers("1 2\n  3 x4 5").unwrap_err();
        assert_eq!(
            err,
            NumberError::Malformed {
                index: 4,
                line: 2,
                column: 5,
                text: "x4".into()
            }
        );
        assert!(matches!(
            parse_numbers("1 nan"),
            Err(NumberError::NotFinite { index: 2, .. })
        ));
    }

    #[test]
    fn exact_count() {
        assert_eq!(parse_exact("1 2 3", 2).unwrap(), vec![1.0, 2.0]);
        assert_eq!(
            parse_exact("1", 2).unwrap_err(),
            NumberError::TooFew {
                expected: 2,
                found: 1
            }
        );
    }
}
