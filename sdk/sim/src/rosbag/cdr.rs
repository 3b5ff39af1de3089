//! CDR (the serialization of ROS 2 messages, XCDR1 as rosbag2 stores it): a decoder driven by
//! a message's [`Definitions`] into a [`Value`] tree, and a small encoder for the messages
//! `human2nav replay` writes.
//!
//! Layout: a 4-byte encapsulation header (`00 01`: little endian, `00 00`: big endian, then two
//! option bytes), then the fields in order, each primitive aligned to its size (at most 8)
//! counted from the end of the header; a string is a `uint32` length counting its NUL, the
//! bytes and the NUL; a sequence a `uint32` count and its elements; a fixed array its elements.

use super::msgdef::{Arity, Definitions, FieldType};

/// A decoded value.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// `bool`.
    Bool(bool),
    /// A signed integer.
    Int(i64),
    /// An unsigned integer (`byte`, `char`, `uint*`).
    UInt(u64),
    /// `float32` or `float64`.
    Float(f64),
    /// `string` or `wstring`.
    Str(String),
    /// An array or a sequence.
    List(Vec<Value>),
    /// A message: its fields in order.
    Struct(Vec<(String, Value)>),
}

impl Value {
    /// The value at `path` (`pose.pose.position.x`); `None` when it is not there.
    pub fn get(&self, path: &str) -> Option<&Value> {
        path.split('.').try_fold(self, |v, part| match v {
            Value::Struct(fields) => fields.iter().find(|(n, _)| n == part).map(|(_, v)| v),
            _ => None,
        })
    }

    /// The number at `path` (any numeric value), `None` when it is not one.
    pub fn number(&self, path: &str) -> Option<f64> {
        match self.get(path)? {
            Value::Float(f) => Some(*f),
            Value::Int(i) => Some(*i as f64),
            Value::UInt(u) => Some(*u as f64),
            _ => None,
        }
    }

    /// The text at `path`.
    pub fn text(&self, path: &str) -> Option<&str> {
        match self.get(path)? {
            Value::Str(s) => Some(s),
            _ => None,
        }
    }

    /// The list at `path`.
    pub fn list(&self, path: &str) -> Option<&[Value]> {
        match self.get(path)? {
            Value::List(l) => Some(l),
            _ => None,
        }
    }
}

/// Longest sequence or string accepted (elements or bytes): a corrupt count fails here rather
/// than by exhausting memory.
const MAX_LEN: usize = 1 << 26;

struct Reader<'a> {
    data: &'a [u8],
    at: usize,
    little: bool,
}

impl Reader<'_> {
    fn align(&mut self, n: usize) {
        let rel = self.at - 4;
        self.at += (n - rel % n) % n;
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&[u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.data.len());
        match end {
            Some(end) => {
                let s = &self.data[self.at..end];
                self.at = end;
                Ok(s)
            }
            None => Err(format!(
                "truncated: {n} bytes of `{what}` at byte {} of {}",
                self.at,
                self.data.len()
            )),
        }
    }

    fn fixed<const N: usize>(&mut self, what: &str) -> Result<[u8; N], String> {
        self.align(N.min(8));
        let s = self.take(N, what)?;
        let mut b = [0u8; N];
        b.copy_from_slice(s);
        if !self.little {
            b.reverse();
        }
        Ok(b)
    }

    fn u32(&mut self, what: &str) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.fixed::<4>(what)?))
    }

    fn builtin(&mut self, t: &str, what: &str) -> Result<Value, String> {
        Ok(match t {
            "bool" => Value::Bool(self.fixed::<1>(what)?[0] != 0),
            "byte" | "char" | "uint8" => Value::UInt(u64::from(self.fixed::<1>(what)?[0])),
            "int8" => Value::Int(i64::from(i8::from_le_bytes(self.fixed::<1>(what)?))),
            "int16" => Value::Int(i64::from(i16::from_le_bytes(self.fixed::<2>(what)?))),
            "uint16" => Value::UInt(u64::from(u16::from_le_bytes(self.fixed::<2>(what)?))),
            "int32" => Value::Int(i64::from(i32::from_le_bytes(self.fixed::<4>(what)?))),
            "uint32" => Value::UInt(u64::from(u32::from_le_bytes(self.fixed::<4>(what)?))),
            "int64" => Value::Int(i64::from_le_bytes(self.fixed::<8>(what)?)),
            "uint64" => Value::UInt(u64::from_le_bytes(self.fixed::<8>(what)?)),
            "float32" => Value::Float(f64::from(f32::from_le_bytes(self.fixed::<4>(what)?))),
            "float64" => Value::Float(f64::from_le_bytes(self.fixed::<8>(what)?)),
            "string" => {
                let n = self.u32(what)? as usize;
                if n > MAX_LEN {
                    return Err(format!("`{what}`: a string of {n} bytes"));
                }
                let bytes = self.take(n, what)?;
                let text = bytes.strip_suffix(&[0]).unwrap_or(bytes);
                Value::Str(String::from_utf8_lossy(text).into_owned())
            }
            "wstring" => {
                let n = self.u32(what)? as usize;
                if n > MAX_LEN {
                    return Err(format!("`{what}`: a string of {n} characters"));
                }
                self.align(4);
                let little = self.little;
                let bytes = self.take(4 * n, what)?;
                let text: String = bytes
                    .chunks(4)
                    .filter_map(|c| {
                        let v = if little {
                            u32::from_le_bytes([c[0], c[1], c[2], c[3]])
                        } else {
                            u32::from_be_bytes([c[0], c[1], c[2], c[3]])
                        };
                        char::from_u32(v)
                    })
                    .filter(|&c| c != '\0')
                    .collect();
                Value::Str(text)
            }
            other => return Err(format!("`{what}`: unknown built-in type `{other}`")),
        })
    }

    fn message(&mut self, defs: &Definitions, ty: &str, path: &str) -> Result<Value, String> {
        let fields = defs
            .types
            .get(ty)
            .ok_or_else(|| format!("no definition of `{ty}`"))?;
        let mut out = Vec::with_capacity(fields.len());
        for f in fields {
            let what = if path.is_empty() {
                f.name.clone()
            } else {
                format!("{path}.{}", f.name)
            };
            let one = |r: &mut Self| match &f.ty {
                FieldType::Builtin(b) => r.builtin(b, &what),
                FieldType::Message(m) => r.message(defs, m, &what),
            };
            let v = match f.arity {
                Arity::One => one(self)?,
                Arity::Fixed(n) => {
                    Value::List((0..n).map(|_| one(self)).collect::<Result<_, _>>()?)
                }
                Arity::Sequence => {
                    let n = self.u32(&what)? as usize;
                    if n > MAX_LEN || n > self.data.len() {
                        return Err(format!(
                            "`{what}`: a sequence of {n} elements in {} bytes",
                            self.data.len()
                        ));
                    }
                    Value::List((0..n).map(|_| one(self)).collect::<Result<_, _>>()?)
                }
            };
            out.push((f.name.clone(), v));
        }
        Ok(Value::Struct(out))
    }
}

/// Decodes one CDR message of `defs`' root type; the error says where it stopped.
pub fn decode(defs: &Definitions, data: &[u8]) -> Result<Value, String> {
    if data.len() < 4 {
        return Err(format!("{} bytes, shorter than the CDR header", data.len()));
    }
    let little = match (data[0], data[1]) {
        (0, 1) => true,
        (0, 0) => false,
        (a, b) => {
            return Err(format!(
                "encapsulation {a:02x} {b:02x} is not plain CDR (00 00 or 00 01)"
            ));
        }
    };
    let mut r = Reader {
        data,
        at: 4,
        little,
    };
    r.message(defs, &defs.root, "")
}

/// A little-endian CDR message being written.
#[derive(Debug)]
pub struct Writer {
    buf: Vec<u8>,
}

impl Default for Writer {
    fn default() -> Self {
        Self::new()
    }
}

impl Writer {
    /// A message with its little-endian encapsulation header.
    pub fn new() -> Self {
        Self {
            buf: vec![0, 1, 0, 0],
        }
    }

    fn align(&mut self, n: usize) {
        let rel = self.buf.len() - 4;
        let pad = (n - rel % n) % n;
        self.buf.extend(std::iter::repeat_n(0u8, pad));
    }

    /// An `int32`.
    pub fn i32(&mut self, v: i32) -> &mut Self {
        self.align(4);
        self.buf.extend(v.to_le_bytes());
        self
    }

    /// A `uint32` (also a sequence's count).
    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.align(4);
        self.buf.extend(v.to_le_bytes());
        self
    }

    /// A `float64`.
    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.align(8);
        self.buf.extend(v.to_le_bytes());
        self
    }

    /// A `string`.
    pub fn string(&mut self, s: &str) -> &mut Self {
        self.u32(u32::try_from(s.len() + 1).unwrap_or(u32::MAX));
        self.buf.extend(s.as_bytes());
        self.buf.push(0);
        self
    }

    /// The bytes written.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

#[cfg(test)]
mod tests {
    use super::super::msgdef::parse;
    use super::*;

    #[test]
    fn a_written_message_decodes_with_alignment_and_a_truncated_one_says_where() {
        let defs = parse(
            "t/M",
            "uint8 flag\nfloat64 x\nstring name\nint32[] ids\nt/P[2] points\n\
             ===\nMSG: t/P\nfloat32 a\nfloat64 b\n",
        )
        .unwrap();
        let mut w = Writer::new();
        w.buf.push(7); // uint8
        w.f64(1.5).string("hi").u32(2).i32(-3).i32(4);
        for (a, b) in [(0.5f32, 2.0), (1.0, -1.0)] {
            w.align(4);
            w.buf.extend(a.to_le_bytes());
            w.f64(b);
        }
        let bytes = w.finish();
        let v = decode(&defs, &bytes).unwrap();
        assert_eq!(v.number("flag"), Some(7.0));
        assert_eq!(v.number("x"), Some(1.5));
        assert_eq!(v.text("name"), Some("hi"));
        assert_eq!(v.list("ids"), Some(&[Value::Int(-3), Value::Int(4)][..]));
        let points = v.list("points").unwrap();
        assert_eq!(points[1].number("b"), Some(-1.0));
        assert_eq!(points[0].number("a"), Some(0.5));
        let e = decode(&defs, &bytes[..bytes.len() - 3]).unwrap_err();
        assert!(e.contains("truncated") && e.contains("`points.b`"), "{e}");
        let e = decode(&defs, &[1, 2, 0, 0, 0]).unwrap_err();
        assert!(e.contains("not plain CDR"), "{e}");
    }
}
