//! A ULog writer (PX4's log format, as its documentation "ULog File Format" specifies it):
//! the header, the flag bits, message formats, information and parameters, then
//! subscriptions, data and logged strings, little endian. What Flight Review, PlotJuggler and
//! pyulog read. Pure: it fills a byte buffer.

use std::collections::HashMap;

/// The header's magic and file version 1.
const MAGIC: [u8; 8] = [0x55, 0x4c, 0x6f, 0x67, 0x01, 0x12, 0x35, 0x01];

/// A field's type, as a format names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Type {
    U8,
    U32,
    I32,
    F32,
    F64,
    Bool,
}

impl Type {
    fn name(self) -> &'static str {
        match self {
            Type::U8 => "uint8_t",
            Type::U32 => "uint32_t",
            Type::I32 => "int32_t",
            Type::F32 => "float",
            Type::F64 => "double",
            Type::Bool => "bool",
        }
    }
}

/// A value of a data message's field (after its timestamp).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    U8(u8),
    U32(u32),
    I32(i32),
    F32(f32),
    F64(f64),
    Bool(bool),
}

impl Value {
    fn ty(self) -> Type {
        match self {
            Value::U8(_) => Type::U8,
            Value::U32(_) => Type::U32,
            Value::I32(_) => Type::I32,
            Value::F32(_) => Type::F32,
            Value::F64(_) => Type::F64,
            Value::Bool(_) => Type::Bool,
        }
    }

    fn put(self, out: &mut Vec<u8>) {
        match self {
            Value::U8(v) => out.push(v),
            Value::U32(v) => out.extend_from_slice(&v.to_le_bytes()),
            Value::I32(v) => out.extend_from_slice(&v.to_le_bytes()),
            Value::F32(v) => out.extend_from_slice(&v.to_le_bytes()),
            Value::F64(v) => out.extend_from_slice(&v.to_le_bytes()),
            Value::Bool(v) => out.push(u8::from(v)),
        }
    }
}

/// A topic's fields after its `uint64_t timestamp`: (name, type, array length; 1 = scalar).
pub type Fields = &'static [(&'static str, Type, usize)];

/// A logged string's level (the Linux kernel's, as ULog's 'L' message carries it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    Critical,
    Warning,
    Info,
}

impl Level {
    fn byte(self) -> u8 {
        match self {
            Level::Critical => b'2',
            Level::Warning => b'4',
            Level::Info => b'6',
        }
    }
}

/// One message of the data section, kept until [`Ulog::finish`] orders them by time.
struct Entry {
    t_us: u64,
    /// Order of arrival: equal times keep it.
    seq: usize,
    bytes: Vec<u8>,
}

/// A ULog being built: definitions as they are declared, data in time order at the end.
pub struct Ulog {
    defs: Vec<u8>,
    topics: HashMap<&'static str, (u16, Fields)>,
    subscriptions: Vec<u8>,
    data: Vec<Entry>,
}

/// Appends a message: its size (without the 3-byte header), its type, its payload.
fn message(out: &mut Vec<u8>, kind: u8, payload: &[u8]) -> Result<(), String> {
    let size = u16::try_from(payload.len()).map_err(|_| {
        format!(
            "ULog message {} of {} bytes: too long",
            kind as char,
            payload.len()
        )
    })?;
    out.extend_from_slice(&size.to_le_bytes());
    out.push(kind);
    out.extend_from_slice(payload);
    Ok(())
}

/// An information or parameter message's payload: the key ("type name") and the value.
fn key_value(key: &str, value: &[u8]) -> Result<Vec<u8>, String> {
    let len = u8::try_from(key.len()).map_err(|_| format!("ULog key {key:?}: too long"))?;
    let mut p = vec![len];
    p.extend_from_slice(key.as_bytes());
    p.extend_from_slice(value);
    Ok(p)
}

impl Ulog {
    /// A log whose clock starts at `start_us` (the header's timestamp), with the flag bits
    /// (none set).
    pub fn new(start_us: u64) -> Self {
        let mut defs = Vec::with_capacity(4096);
        defs.extend_from_slice(&MAGIC);
        defs.extend_from_slice(&start_us.to_le_bytes());
        // Flag bits: no compatibility flags, no incompatible ones, no appended data.
        let _ = message(&mut defs, b'B', &[0u8; 40]);
        Ulog {
            defs,
            topics: HashMap::new(),
            subscriptions: Vec::new(),
            data: Vec::new(),
        }
    }

    /// An information string (`sys_name`, `ver_sw`, ...).
    pub fn info(&mut self, name: &str, value: &str) -> Result<(), String> {
        let key = format!("char[{}] {name}", value.len());
        message(&mut self.defs, b'I', &key_value(&key, value.as_bytes())?)
    }

    /// A parameter, as a float.
    pub fn param(&mut self, name: &str, value: f32) -> Result<(), String> {
        let key = format!("float {name}");
        message(
            &mut self.defs,
            b'P',
            &key_value(&key, &value.to_le_bytes())?,
        )
    }

    /// Declares topic `name` (its format and its subscription).
    pub fn topic(&mut self, name: &'static str, fields: Fields) -> Result<(), String> {
        let mut format = format!("{name}:uint64_t timestamp;");
        for (field, ty, n) in fields {
            match n {
                1 => format += &format!("{} {field};", ty.name()),
                n => format += &format!("{}[{n}] {field};", ty.name()),
            }
        }
        message(&mut self.defs, b'F', format.as_bytes())?;
        let id = u16::try_from(self.topics.len()).map_err(|_| "too many ULog topics")?;
        let mut sub = vec![0u8];
        sub.extend_from_slice(&id.to_le_bytes());
        sub.extend_from_slice(name.as_bytes());
        message(&mut self.subscriptions, b'A', &sub)?;
        self.topics.insert(name, (id, fields));
        Ok(())
    }

    /// One sample of `topic` at `t_us`: its values in the declared order, arrays flattened.
    pub fn data(&mut self, topic: &str, t_us: u64, values: &[Value]) -> Result<(), String> {
        let bytes = self.data_message(topic, t_us, values)?;
        self.push(t_us, bytes);
        Ok(())
    }

    /// [`Ulog::data`]'s message, for a writer that orders the data itself (a streamed
    /// export merges its logs by time).
    pub fn data_message(
        &self,
        topic: &str,
        t_us: u64,
        values: &[Value],
    ) -> Result<Vec<u8>, String> {
        let (id, fields) = *self
            .topics
            .get(topic)
            .ok_or_else(|| format!("ULog topic {topic} not declared"))?;
        let types = fields
            .iter()
            .flat_map(|(_, ty, n)| std::iter::repeat_n(*ty, *n));
        if !types.clone().eq(values.iter().map(|v| v.ty())) {
            return Err(format!(
                "ULog topic {topic}: values {values:?} do not match its format"
            ));
        }
        let mut p = Vec::with_capacity(10 + 8 * values.len());
        p.extend_from_slice(&id.to_le_bytes());
        p.extend_from_slice(&t_us.to_le_bytes());
        for v in values {
            v.put(&mut p);
        }
        let mut bytes = Vec::with_capacity(p.len() + 3);
        message(&mut bytes, b'D', &p)?;
        Ok(bytes)
    }

    /// A logged string at `t_us`.
    pub fn log(&mut self, level: Level, t_us: u64, text: &str) -> Result<(), String> {
        let bytes = Self::log_message(level, t_us, text)?;
        self.push(t_us, bytes);
        Ok(())
    }

    /// [`Ulog::log`]'s message.
    pub fn log_message(level: Level, t_us: u64, text: &str) -> Result<Vec<u8>, String> {
        let mut p = vec![level.byte()];
        p.extend_from_slice(&t_us.to_le_bytes());
        p.extend_from_slice(text.as_bytes());
        let mut bytes = Vec::with_capacity(p.len() + 3);
        message(&mut bytes, b'L', &p)?;
        Ok(bytes)
    }

    fn push(&mut self, t_us: u64, bytes: Vec<u8>) {
        let seq = self.data.len();
        self.data.push(Entry { t_us, seq, bytes });
    }

    /// The bytes before the data: header, definitions, subscriptions.
    pub fn head(&self) -> Vec<u8> {
        let mut out = self.defs.clone();
        out.extend_from_slice(&self.subscriptions);
        out
    }

    /// The file's bytes: definitions, subscriptions, then the data in time order.
    pub fn finish(mut self) -> Vec<u8> {
        self.data.sort_by_key(|e| (e.t_us, e.seq));
        let mut out = self.head();
        for e in self.data {
            out.extend_from_slice(&e.bytes);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FIELDS: Fields = &[
        ("x", Type::F64, 1),
        ("q", Type::F32, 2),
        ("ok", Type::Bool, 1),
    ];

    fn u16_at(b: &[u8], i: usize) -> usize {
        usize::from(u16::from_le_bytes([b[i], b[i + 1]]))
    }

    /// The messages after the header: (type, payload).
    fn messages(b: &[u8]) -> Vec<(u8, Vec<u8>)> {
        let mut out = Vec::new();
        let mut i = 16;
        while i < b.len() {
            let size = u16_at(b, i);
            out.push((b[i + 2], b[i + 3..i + 3 + size].to_vec()));
            i += 3 + size;
        }
        out
    }

    #[test]
    fn a_log_is_header_definitions_then_time_ordered_data() {
        let mut u = Ulog::new(7);
        u.info("sys_name", "uquad").unwrap();
        u.param("MIS_SPEED_M_S", 1.5).unwrap();
        u.topic("t", FIELDS).unwrap();
        let v = [
            Value::F64(2.5),
            Value::F32(1.0),
            Value::F32(-1.0),
            Value::Bool(true),
        ];
        u.data("t", 20, &v).unwrap();
        u.log(Level::Info, 10, "hello").unwrap();
        u.data("t", 10, &v).unwrap();
        let b = u.finish();
        assert_eq!(&b[..8], &MAGIC);
        assert_eq!(u64::from_le_bytes(b[8..16].try_into().unwrap()), 7);
        let m = messages(&b);
        let kinds: Vec<char> = m.iter().map(|(k, _)| *k as char).collect();
        assert_eq!(kinds, ['B', 'I', 'P', 'F', 'A', 'L', 'D', 'D']);
        assert_eq!(m[1].1, b"\x10char[5] sys_nameuquad");
        assert_eq!(
            &m[3].1[..],
            b"t:uint64_t timestamp;double x;float[2] q;bool ok;"
        );
        // The log line at 10 before the data at 10 (arrival order), then the one at 20.
        let d = &m[6].1;
        assert_eq!(u16_at(d, 0), 0);
        assert_eq!(u64::from_le_bytes(d[2..10].try_into().unwrap()), 10);
        assert_eq!(f64::from_le_bytes(d[10..18].try_into().unwrap()), 2.5);
        assert_eq!(d.len(), 2 + 8 + 8 + 4 + 4 + 1);
        assert_eq!(m[5].1[0], b'6');
    }

    #[test]
    fn values_that_do_not_fit_the_format_are_refused() {
        let mut u = Ulog::new(0);
        u.topic("t", FIELDS).unwrap();
        assert!(u.data("t", 0, &[Value::F64(1.0)]).is_err());
        assert!(u.data("nope", 0, &[]).is_err());
        assert!(u.log(Level::Info, 0, &"x".repeat(70_000)).is_err());
    }
}
