//! A run log read a line at a time, for the tools whose memory must not grow with a log's
//! length (`uquad export --format csv`): each line bounded to [`LINE_MAX`] bytes; a line over
//! it, a last line cut off (no line end: a power cut), or a line not understood is counted,
//! skipped and reported — never fatal. Blank lines and `#` comments are no records.

use crate::config::bounded;
use anyhow::Context;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

/// The longest line taken, bytes: the longest record (an err.log note) is far shorter.
pub const LINE_MAX: usize = 64 * 1024;

/// What a log's reading skipped.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Skipped {
    pub over_long: u64,
    pub cut_off: u64,
    pub malformed: u64,
    /// The first line skipped: its number and why.
    pub first: Option<(u64, String)>,
}

impl Skipped {
    pub fn total(&self) -> u64 {
        self.over_long + self.cut_off + self.malformed
    }

    fn note(&mut self, line: u64, why: String) {
        self.first.get_or_insert((line, why));
    }
}

/// One log, open for reading line by line.
pub struct LogLines {
    path: PathBuf,
    reader: BufReader<std::fs::File>,
    buf: Vec<u8>,
    line: u64,
    /// Records returned so far.
    records: u64,
    /// The last line read had no line end (the file's last).
    unended: bool,
    pub skipped: Skipped,
}

impl LogLines {
    /// `path` open for reading; `None` when it does not exist (a stream the run did not
    /// write). Only a regular file is read.
    pub fn open(path: &Path) -> anyhow::Result<Option<LogLines>> {
        let file = match bounded::open_regular(path) {
            Ok(f) => f,
            Err(e) if e.missing => return Ok(None),
            Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
        };
        Ok(Some(LogLines {
            path: path.to_path_buf(),
            reader: BufReader::with_capacity(64 * 1024, file),
            buf: Vec::with_capacity(256),
            line: 0,
            records: 0,
            unended: false,
            skipped: Skipped::default(),
        }))
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The next line that is a record (trimmed, not blank, not a comment); `None` at the end.
    pub fn next_text(&mut self) -> anyhow::Result<Option<&str>> {
        Ok(self
            .next_range()?
            .and_then(|(start, end)| std::str::from_utf8(&self.buf[start..end]).ok()))
    }

    /// The next line as written, without its line end (blank and `#` lines included: err.log
    /// and mode.log are text, not records); `None` at the end.
    pub fn next_raw(&mut self) -> anyhow::Result<Option<&str>> {
        Ok(self.next_span(false)?.and_then(|(start, end)| {
            let line = std::str::from_utf8(&self.buf[start..end]).ok()?;
            Some(line.strip_suffix('\r').unwrap_or(line))
        }))
    }

    /// Where in the buffer the next record's text lies.
    fn next_range(&mut self) -> anyhow::Result<Option<(usize, usize)>> {
        self.next_span(true)
    }

    /// The next line's span in the buffer: a record's (trimmed; blank and `#` lines passed
    /// over) when `records`, else the whole line without its `\n`.
    fn next_span(&mut self, records: bool) -> anyhow::Result<Option<(usize, usize)>> {
        loop {
            self.buf.clear();
            let limit = LINE_MAX as u64 + 1;
            let n = (&mut self.reader)
                .take(limit)
                .read_until(b'\n', &mut self.buf)
                .with_context(|| format!("cannot read {}", self.path.display()))?;
            if n == 0 {
                return Ok(None);
            }
            self.line += 1;
            if self.buf.last() != Some(&b'\n') {
                if n as u64 == limit {
                    self.skip_rest_of_line()?;
                    self.skipped.over_long += 1;
                    self.skipped
                        .note(self.line, format!("over {LINE_MAX} bytes"));
                    continue;
                }
                // The file's last line, without its end: taken if it reads (a file written
                // without a final line end); a record that does not is counted cut off.
                self.unended = true;
                self.buf.push(b'\n');
            }
            let Ok(text) = std::str::from_utf8(&self.buf) else {
                self.skipped.malformed += 1;
                self.skipped.note(self.line, "not UTF-8 text".into());
                continue;
            };
            if !records {
                return Ok(Some((0, text.len() - 1)));
            }
            let body = text.trim();
            if body.is_empty() || body.starts_with('#') {
                continue;
            }
            let start = text.len() - text.trim_start().len();
            return Ok(Some((start, start + body.len())));
        }
    }

    /// The next record parsed from its whitespace-separated fields; a line `parse` does not
    /// understand is counted and skipped.
    pub fn next<T>(
        &mut self,
        parse: impl Fn(&[&str]) -> Result<T, String>,
    ) -> anyhow::Result<Option<T>> {
        loop {
            let parsed = {
                let Some(text) = self.next_text()? else {
                    return Ok(None);
                };
                let fields: Vec<&str> = text.split_ascii_whitespace().collect();
                parse(&fields)
            };
            match parsed {
                Ok(r) => {
                    self.records += 1;
                    return Ok(Some(r));
                }
                Err(why) if self.unended => {
                    self.skipped.cut_off += 1;
                    let line = self.line;
                    self.skipped
                        .note(line, format!("cut off (no line end): {why}"));
                }
                Err(why) => {
                    self.skipped.malformed += 1;
                    let line = self.line;
                    self.skipped.note(line, why);
                }
            }
        }
    }

    /// Just after [`LogLines::next`] gave a record: its index among the log's record lines
    /// (comments and blank lines not counted, skipped lines counted). Two logs written a line
    /// per step (x_hat, kalman_in) pair by it even when one of them lost a line.
    pub fn last_index(&self) -> u64 {
        (self.records + self.skipped.total()).saturating_sub(1)
    }

    /// Reads past the rest of an over-long line without keeping it.
    fn skip_rest_of_line(&mut self) -> anyhow::Result<()> {
        loop {
            let chunk = self
                .reader
                .fill_buf()
                .with_context(|| format!("cannot read {}", self.path.display()))?;
            if chunk.is_empty() {
                return Ok(());
            }
            match chunk.iter().position(|&b| b == b'\n') {
                Some(i) => {
                    self.reader.consume(i + 1);
                    return Ok(());
                }
                None => {
                    let n = chunk.len();
                    self.reader.consume(n);
                }
            }
        }
    }

    /// What was skipped, as a line for the user; `None` when nothing was.
    pub fn warning(&self) -> Option<String> {
        let s = &self.skipped;
        let (line, why) = s.first.as_ref()?;
        Some(format!(
            "{}: {} line(s) skipped ({} over {LINE_MAX} bytes, {} cut off, {} not understood); the first, line {line}: {why}",
            self.path.display(),
            s.total(),
            s.over_long,
            s.cut_off,
            s.malformed
        ))
    }
}

/// The time of each estimate, µs, read alongside x_hat.log: kalman_in's record on the same
/// line index; past kalman_in's end (the original's x_hat.log has one row more than its
/// kalman_in.log), or where kalman_in lost that line, 10 ms a line after the last one known.
pub struct EstimateTimes {
    lines: Option<LogLines>,
    /// The newest kalman_in record read and not yet used: its line index and time.
    pending: Option<(u64, i64)>,
    /// The last one used.
    last: Option<(u64, i64)>,
}

impl EstimateTimes {
    pub fn open(run_dir: &Path) -> anyhow::Result<Self> {
        Ok(EstimateTimes {
            lines: LogLines::open(&run_dir.join("kalman_in.log"))?,
            pending: None,
            last: None,
        })
    }

    /// The time of the estimate on x_hat.log's line `index` ([`LogLines::last_index`]).
    pub fn at(&mut self, index: u64) -> anyhow::Result<i64> {
        while let Some(lines) = self.lines.as_mut() {
            match self.pending {
                Some((i, t)) if i == index => {
                    self.last = self.pending.take();
                    return Ok(t);
                }
                // kalman_in has no record on this line: from the last one known.
                Some((i, _)) if i > index => break,
                Some(_) => self.last = self.pending.take(),
                None => {}
            }
            let parse = |f: &[&str]| crate::logs::KalmanInRecord::parse_fields(f).map(|k| k.t_us);
            match lines.next(parse)? {
                Some(t) => self.pending = Some((lines.last_index(), t)),
                None => self.lines = None,
            }
        }
        Ok(match self.last {
            Some((i, t)) => {
                let lines_on = i64::try_from(index.saturating_sub(i)).unwrap_or(i64::MAX);
                t.saturating_add(lines_on.saturating_mul(10_000))
            }
            None => i64::try_from(index)
                .unwrap_or(i64::MAX)
                .saturating_mul(10_000),
        })
    }

    /// kalman_in.log's skipped lines, if any (for a reader that does not read it otherwise).
    pub fn warning(&self) -> Option<String> {
        self.lines.as_ref().and_then(LogLines::warning)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn over_long_cut_off_and_unreadable_lines_are_counted_and_skipped() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.log");
        let long = "9".repeat(LINE_MAX + 10);
        let text = format!("# header\n1 2\r\n\n{long}\nx y\n3 4\n5");
        std::fs::write(&path, text).unwrap();
        let mut lines = LogLines::open(&path).unwrap().unwrap();
        let parse = |f: &[&str]| -> Result<(i64, i64), String> {
            match f {
                [a, b] => Ok((
                    a.parse().map_err(|_| "not a number")?,
                    b.parse().map_err(|_| "not a number")?,
                )),
                _ => Err("two numbers".into()),
            }
        };
        let mut got = Vec::new();
        while let Some(r) = lines.next(parse).unwrap() {
            got.push((r, lines.last_index()));
        }
        // (3, 4) is record line 3, after a line too long and one not understood.
        assert_eq!(got, [((1, 2), 0), ((3, 4), 3)]);
        let s = &lines.skipped;
        assert_eq!((s.over_long, s.malformed, s.cut_off), (1, 1, 1));
        assert_eq!(s.first, Some((4, format!("over {LINE_MAX} bytes"))));
        let w = lines.warning().unwrap();
        assert!(w.contains("line 4: over"), "{w}");
        let w = lines.warning().unwrap();
        assert!(w.contains("3 line(s) skipped"), "{w}");
        assert!(
            LogLines::open(&dir.path().join("none.log"))
                .unwrap()
                .is_none()
        );
        assert!(LogLines::open(dir.path()).is_err(), "a folder is no log");
        // Estimates pair with kalman_in by line, whichever of the two lost one.
        std::fs::write(dir.path().join("kalman_in.log"), "").unwrap();
        let mut none = EstimateTimes::open(dir.path()).unwrap();
        assert_eq!((none.at(0).unwrap(), none.at(1).unwrap()), (0, 10_000));
        // A last line without its end that reads is taken.
        std::fs::write(&path, "1 2\n3 4").unwrap();
        let mut unended = LogLines::open(&path).unwrap().unwrap();
        assert_eq!(unended.next(parse).unwrap(), Some((1, 2)));
        assert_eq!(unended.next(parse).unwrap(), Some((3, 4)));
        assert_eq!(unended.skipped.total(), 0);
        // Raw lines keep their text, blank and comment lines included.
        std::fs::write(&path, "  a b \r\n# c\n\nlast").unwrap();
        let mut raw = LogLines::open(&path).unwrap().unwrap();
        assert_eq!(raw.next_raw().unwrap(), Some("  a b "));
        assert_eq!(raw.next_raw().unwrap(), Some("# c"));
        assert_eq!(raw.next_raw().unwrap(), Some(""));
        assert_eq!(
            raw.next_raw().unwrap(),
            Some("last"),
            "a last line without its end"
        );
        assert_eq!(raw.next_raw().unwrap(), None);
    }
}
