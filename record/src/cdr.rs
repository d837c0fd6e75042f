//! The encoding of every message in a recording: CDR (little endian, the byte layout ROS 2 uses),
//! described by a `ros2msg` schema, so Foxglove and Lichtblick decode and plot the channels.
//!
//! Each recorded type implements [`Field`] once, and that one list of fields gives its schema
//! text, its encoding, its decoding and its CSV columns, so they cannot disagree. Decoding
//! checks every length and code and never panics: a recording is outside input.
//!
//! Layout: a 4-byte encapsulation header (`00 01 00 00`: plain CDR, little endian), then the
//! fields in order, each primitive aligned to its own size (at most 8) from the end of the header;
//! fixed arrays inline, sequences as a `uint32` count then the items, strings as a `uint32` length
//! counting a final NUL, then the bytes and the NUL.

use std::fmt::Write as _;

/// Why bytes did not decode.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{what} at byte {at}")]
pub struct DecodeError {
    pub what: String,
    pub at: usize,
}

/// Writes one message.
pub struct Writer<'a> {
    buf: &'a mut Vec<u8>,
    start: usize,
}

const HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

impl<'a> Writer<'a> {
    /// Appends the encapsulation header to `buf` and writes after it.
    pub fn new(buf: &'a mut Vec<u8>) -> Writer<'a> {
        buf.extend_from_slice(&HEADER);
        let start = buf.len();
        Writer { buf, start }
    }
    fn align(&mut self, n: usize) {
        while !(self.buf.len() - self.start).is_multiple_of(n) {
            self.buf.push(0);
        }
    }
    pub fn u8(&mut self, x: u8) {
        self.buf.push(x);
    }
    pub fn u16(&mut self, x: u16) {
        self.align(2);
        self.buf.extend_from_slice(&x.to_le_bytes());
    }
    pub fn u32(&mut self, x: u32) {
        self.align(4);
        self.buf.extend_from_slice(&x.to_le_bytes());
    }
    pub fn i32(&mut self, x: i32) {
        self.align(4);
        self.buf.extend_from_slice(&x.to_le_bytes());
    }
    pub fn u64(&mut self, x: u64) {
        self.align(8);
        self.buf.extend_from_slice(&x.to_le_bytes());
    }
    pub fn i64(&mut self, x: i64) {
        self.align(8);
        self.buf.extend_from_slice(&x.to_le_bytes());
    }
    pub fn f64(&mut self, x: f64) {
        self.align(8);
        self.buf.extend_from_slice(&x.to_le_bytes());
    }
    pub fn f32(&mut self, x: f32) {
        self.align(4);
        self.buf.extend_from_slice(&x.to_le_bytes());
    }
    pub fn str(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
}

/// Reads one message.
pub struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    /// Checks the encapsulation header and reads after it.
    pub fn new(data: &'a [u8]) -> Result<Reader<'a>, DecodeError> {
        if data.len() < 4 || data[..4] != HEADER {
            return Err(DecodeError {
                what: "not little-endian CDR (bad encapsulation header)".into(),
                at: 0,
            });
        }
        Ok(Reader { data: &data[4..], pos: 0 })
    }
    fn err(&self, what: impl Into<String>) -> DecodeError {
        DecodeError { what: what.into(), at: self.pos + 4 }
    }
    fn take(&mut self, n: usize, align: usize) -> Result<&'a [u8], DecodeError> {
        let start = self.pos.next_multiple_of(align);
        match self.data.get(start..start.saturating_add(n)) {
            Some(b) => {
                self.pos = start + n;
                Ok(b)
            }
            None => Err(self.err(format!("message ends early ({n} more bytes expected)"))),
        }
    }
    fn array<const N: usize>(&mut self) -> Result<[u8; N], DecodeError> {
        let b = self.take(N, N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(b);
        Ok(a)
    }
    pub fn u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take(1, 1)?[0])
    }
    pub fn u16(&mut self) -> Result<u16, DecodeError> {
        Ok(u16::from_le_bytes(self.array()?))
    }
    pub fn u32(&mut self) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    pub fn i32(&mut self) -> Result<i32, DecodeError> {
        Ok(i32::from_le_bytes(self.array()?))
    }
    pub fn u64(&mut self) -> Result<u64, DecodeError> {
        Ok(u64::from_le_bytes(self.array()?))
    }
    pub fn i64(&mut self) -> Result<i64, DecodeError> {
        Ok(i64::from_le_bytes(self.array()?))
    }
    pub fn f64(&mut self) -> Result<f64, DecodeError> {
        Ok(f64::from_le_bytes(self.array()?))
    }
    pub fn f32(&mut self) -> Result<f32, DecodeError> {
        Ok(f32::from_le_bytes(self.array()?))
    }
    pub fn str(&mut self) -> Result<String, DecodeError> {
        let n = self.u32()? as usize;
        if n == 0 {
            return Err(self.err("string without its final NUL"));
        }
        let b = self.take(n, 1)?;
        if b[n - 1] != 0 {
            return Err(self.err("string without its final NUL"));
        }
        String::from_utf8(b[..n - 1].to_vec()).map_err(|_| self.err("string is not UTF-8"))
    }
    /// A sequence count, checked against what is left (each item takes at least `min_item` bytes).
    pub fn count(&mut self, min_item: usize) -> Result<usize, DecodeError> {
        let n = self.u32()? as usize;
        if n.saturating_mul(min_item.max(1)) > self.data.len() - self.pos {
            return Err(self.err(format!("sequence of {n} items is longer than the message")));
        }
        Ok(n)
    }
    /// Fails unless every byte was used (a schema that does not match leaves some over).
    pub fn finish(&self) -> Result<(), DecodeError> {
        let left = self.data.len() - self.pos;
        // Trailing alignment padding is allowed, nothing more.
        if left >= 8 || self.data[self.pos..].iter().any(|b| *b != 0) {
            return Err(self.err(format!("{left} bytes left over after the message")));
        }
        Ok(())
    }
}

/// A value in a recorded message: its `ros2msg` type, encoding, decoding and CSV columns.
pub trait Field: Sized {
    /// Its type in a `ros2msg` definition (`float64`, `float64[4]`, `spidar/Vec3`).
    fn ros_type() -> String;
    /// For a message type: its fields, one `type name` per line (with `#` comments).
    fn definition() -> Option<String> {
        None
    }
    /// Adds the message types this one uses (itself included, when it is one) to `out`, by name.
    fn collect(out: &mut Vec<(String, String)>) {
        add_definition::<Self>(out);
    }
    fn write(&self, w: &mut Writer<'_>);
    fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError>;
    /// Adds the CSV column names of this value, prefixed by `prefix`.
    fn columns(prefix: &str, out: &mut Vec<String>);
    /// Appends this value's CSV cells, each preceded by a comma.
    fn csv(&self, out: &mut String);
}

/// Adds `T`'s definition to `out` unless it is there already; true when added.
pub fn add_definition<T: Field>(out: &mut Vec<(String, String)>) -> bool {
    let name = T::ros_type();
    match T::definition() {
        Some(d) if !out.iter().any(|(n, _)| *n == name) => {
            out.push((name, d));
            true
        }
        _ => false,
    }
}

/// The full `ros2msg` schema of a top-level message: its definition, then each type it uses.
pub fn schema_text<T: Field>() -> String {
    let mut used = Vec::new();
    T::collect(&mut used);
    let me = T::ros_type();
    let mut s = T::definition().unwrap_or_default();
    for (name, def) in used.iter().filter(|(n, _)| *n != me) {
        let _ = write!(s, "{}\nMSG: {name}\n{def}", "=".repeat(80));
    }
    s
}

/// Encodes one message.
pub fn encode<T: Field>(x: &T, buf: &mut Vec<u8>) {
    buf.clear();
    x.write(&mut Writer::new(buf));
}

/// Decodes one message; every byte must belong to it.
pub fn decode<T: Field>(data: &[u8]) -> Result<T, DecodeError> {
    let mut r = Reader::new(data)?;
    let x = T::read(&mut r)?;
    r.finish()?;
    Ok(x)
}

/// `prefix.name`, or `name` at the top.
pub fn join(prefix: &str, name: &str) -> String {
    if prefix.is_empty() {
        name.to_string()
    } else {
        format!("{prefix}.{name}")
    }
}

fn csv_f64(x: f64, out: &mut String) {
    out.push(',');
    if x.is_finite() {
        let mut b = ryu::Buffer::new();
        out.push_str(b.format_finite(x));
    } else if x.is_nan() {
        out.push_str("NaN");
    } else if x > 0.0 {
        out.push_str("inf");
    } else {
        out.push_str("-inf");
    }
}

fn csv_f32(x: f32, out: &mut String) {
    if x.is_finite() {
        out.push(',');
        let mut b = ryu::Buffer::new();
        out.push_str(b.format_finite(x));
    } else {
        csv_f64(x as f64, out);
    }
}

fn csv_int(x: impl itoa_like::Int, out: &mut String) {
    out.push(',');
    x.push_to(out);
}

/// Integer cells without the formatter's machinery (export writes millions of them).
mod itoa_like {
    pub trait Int {
        fn push_to(self, out: &mut String);
    }
    macro_rules! int {
        ($($t:ty),*) => {$(
            impl Int for $t {
                fn push_to(self, out: &mut String) {
                    let mut buf = [0u8; 24];
                    let mut i = buf.len();
                    let neg = (self as i128) < 0;
                    let mut v = (self as i128).unsigned_abs();
                    loop {
                        i -= 1;
                        buf[i] = b'0' + (v % 10) as u8;
                        v /= 10;
                        if v == 0 {
                            break;
                        }
                    }
                    if neg {
                        i -= 1;
                        buf[i] = b'-';
                    }
                    // Only ASCII digits and '-' were written.
                    out.push_str(std::str::from_utf8(&buf[i..]).unwrap_or("?"));
                }
            }
        )*};
    }
    int!(u8, u16, u32, i32, u64, i64);
}

macro_rules! primitive {
    ($t:ty, $ros:literal, $w:ident, $csv:ident) => {
        impl Field for $t {
            fn ros_type() -> String {
                $ros.into()
            }
            fn write(&self, w: &mut Writer<'_>) {
                w.$w(*self)
            }
            fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
                r.$w()
            }
            fn columns(prefix: &str, out: &mut Vec<String>) {
                out.push(prefix.to_string());
            }
            fn csv(&self, out: &mut String) {
                $csv(*self, out)
            }
        }
    };
}

primitive!(u8, "uint8", u8, csv_int);
primitive!(u16, "uint16", u16, csv_int);
primitive!(u32, "uint32", u32, csv_int);
primitive!(i32, "int32", i32, csv_int);
primitive!(u64, "uint64", u64, csv_int);
primitive!(i64, "int64", i64, csv_int);
primitive!(f64, "float64", f64, csv_f64);
primitive!(f32, "float32", f32, csv_f32);

impl Field for bool {
    fn ros_type() -> String {
        "bool".into()
    }
    fn write(&self, w: &mut Writer<'_>) {
        w.u8(*self as u8)
    }
    fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        match r.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            b => Err(r.err(format!("bool of value {b}"))),
        }
    }
    fn columns(prefix: &str, out: &mut Vec<String>) {
        out.push(prefix.to_string());
    }
    fn csv(&self, out: &mut String) {
        out.push_str(if *self { ",1" } else { ",0" });
    }
}

impl Field for String {
    fn ros_type() -> String {
        "string".into()
    }
    fn write(&self, w: &mut Writer<'_>) {
        w.str(self)
    }
    fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        r.str()
    }
    fn columns(prefix: &str, out: &mut Vec<String>) {
        out.push(prefix.to_string());
    }
    fn csv(&self, out: &mut String) {
        out.push_str(",\"");
        out.push_str(&self.replace('"', "\"\""));
        out.push('"');
    }
}

impl<T: Field, const N: usize> Field for [T; N] {
    fn ros_type() -> String {
        format!("{}[{N}]", T::ros_type())
    }
    fn collect(out: &mut Vec<(String, String)>) {
        T::collect(out)
    }
    fn write(&self, w: &mut Writer<'_>) {
        for x in self {
            x.write(w);
        }
    }
    fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let mut v = Vec::with_capacity(N);
        for _ in 0..N {
            v.push(T::read(r)?);
        }
        v.try_into().map_err(|_| r.err("array of the wrong length"))
    }
    fn columns(prefix: &str, out: &mut Vec<String>) {
        for i in 0..N {
            T::columns(&format!("{prefix}[{i}]"), out);
        }
    }
    fn csv(&self, out: &mut String) {
        for x in self {
            x.csv(out);
        }
    }
}

/// A sequence (`T[]`): a `uint32` count, then the items. In CSV, one cell: the items' cells
/// joined by `;`.
impl<T: Field> Field for Vec<T> {
    fn ros_type() -> String {
        format!("{}[]", T::ros_type())
    }
    fn collect(out: &mut Vec<(String, String)>) {
        T::collect(out)
    }
    fn write(&self, w: &mut Writer<'_>) {
        w.u32(self.len() as u32);
        for x in self {
            x.write(w);
        }
    }
    fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let n = r.count(1)?;
        let mut v = Vec::with_capacity(n);
        for _ in 0..n {
            v.push(T::read(r)?);
        }
        Ok(v)
    }
    fn columns(prefix: &str, out: &mut Vec<String>) {
        out.push(prefix.to_string());
    }
    fn csv(&self, out: &mut String) {
        out.push(',');
        let mut cell = String::new();
        for (i, x) in self.iter().enumerate() {
            let mut one = String::new();
            x.csv(&mut one);
            if i > 0 {
                cell.push(';');
            }
            cell.push_str(one.trim_start_matches(',').replace(',', " ").trim_matches('"'));
        }
        out.push_str(&cell);
    }
}

/// Implements [`Field`] for a struct as a `ros2msg` message of the listed fields, in order. Doc
/// comments on the fields become the schema's comments. Fields of the struct that the message
/// does not carry (filled from other channels) are listed after `skip` and decode as their
/// default, so every field of the struct is named here (the compiler checks it). A field written
/// `name as "wire"` keeps the name `wire` in the schema and the CSV columns (a Rust field renamed
/// after recordings were made with the old name).
#[macro_export]
macro_rules! message {
    (
        $ty:ty = $name:literal {
            $( $(#[doc = $doc:literal])* $field:ident $(as $wire:literal)? : $fty:ty ),* $(,)?
        }
        $( skip { $($skip:ident),* $(,)? } )?
    ) => {
        impl $crate::cdr::Field for $ty {
            fn ros_type() -> String {
                $name.into()
            }
            fn definition() -> Option<String> {
                let mut d = String::new();
                $(
                    $( d.push('#'); d.push_str($doc.trim_end()); d.push('\n'); )*
                    d.push_str(&<$fty as $crate::cdr::Field>::ros_type());
                    d.push(' ');
                    d.push_str($crate::wire_name!($field $(, $wire)?));
                    d.push('\n');
                )*
                Some(d)
            }
            fn collect(out: &mut Vec<(String, String)>) {
                if $crate::cdr::add_definition::<Self>(out) {
                    $( <$fty as $crate::cdr::Field>::collect(out); )*
                }
            }
            fn write(&self, w: &mut $crate::cdr::Writer<'_>) {
                $( $crate::cdr::Field::write(&self.$field, w); )*
            }
            fn read(r: &mut $crate::cdr::Reader<'_>) -> Result<Self, $crate::cdr::DecodeError> {
                Ok(Self {
                    $( $field: <$fty as $crate::cdr::Field>::read(r)?, )*
                    $( $( $skip: Default::default(), )* )?
                })
            }
            fn columns(prefix: &str, out: &mut Vec<String>) {
                $( <$fty as $crate::cdr::Field>::columns(&$crate::cdr::join(prefix, $crate::wire_name!($field $(, $wire)?)), out); )*
            }
            fn csv(&self, out: &mut String) {
                $( $crate::cdr::Field::csv(&self.$field, out); )*
            }
        }
    };
}

/// The name of a message field in the schema: its `as "wire"` name, else the Rust field's.
#[macro_export]
macro_rules! wire_name {
    ($field:ident) => {
        stringify!($field).trim_start_matches("r#")
    };
    ($field:ident, $wire:literal) => {
        $wire
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Pair {
        a: u8,
        b: f64,
        c: [u16; 3],
        s: String,
    }
    crate::message!(Pair = "test/Pair" {
        /// one byte
        a: u8,
        b: f64,
        c: [u16; 3],
        s: String,
    });

    #[test]
    fn primitives_are_aligned_from_the_end_of_the_header() {
        let p = Pair { a: 7, b: 1.5, c: [1, 2, 3], s: "hi".into() };
        let mut buf = Vec::new();
        encode(&p, &mut buf);
        // header 4 | a 1 | pad 7 | b 8 | c 6 | pad 2 | len 4 | "hi\0" 3
        assert_eq!(buf.len(), 4 + 1 + 7 + 8 + 6 + 2 + 4 + 3);
        assert_eq!(&buf[..5], &[0, 1, 0, 0, 7]);
        assert_eq!(&buf[12..20], &1.5f64.to_le_bytes());
        let q: Pair = decode(&buf).unwrap();
        assert_eq!((q.a, q.b, q.c, q.s.as_str()), (7, 1.5, [1, 2, 3], "hi"));
    }

    #[test]
    fn the_schema_lists_fields_with_comments() {
        assert_eq!(schema_text::<Pair>(), "# one byte\nuint8 a\nfloat64 b\nuint16[3] c\nstring s\n");
        let mut cols = Vec::new();
        Pair::columns("", &mut cols);
        assert_eq!(cols, ["a", "b", "c[0]", "c[1]", "c[2]", "s"]);
    }

    #[derive(Debug, PartialEq)]
    struct Renamed {
        pos_rig_m: f64,
    }
    crate::message!(Renamed = "test/Renamed" { pos_rig_m as "pos_m": f64 });

    #[test]
    fn a_renamed_field_keeps_its_old_name_in_the_schema_and_the_columns() {
        assert_eq!(schema_text::<Renamed>(), "float64 pos_m\n");
        let mut cols = Vec::new();
        Renamed::columns("hand", &mut cols);
        assert_eq!(cols, ["hand.pos_m"]);
        let mut buf = Vec::new();
        encode(&Renamed { pos_rig_m: 2.5 }, &mut buf);
        assert_eq!(decode::<Renamed>(&buf).unwrap(), Renamed { pos_rig_m: 2.5 });
    }

    #[test]
    fn short_long_and_foreign_bytes_are_errors() {
        let p = Pair { a: 1, b: 2.0, c: [0; 3], s: "x".into() };
        let mut buf = Vec::new();
        encode(&p, &mut buf);
        for n in 0..buf.len() {
            assert!(decode::<Pair>(&buf[..n]).is_err(), "cut at {n}");
        }
        let mut long = buf.clone();
        long.extend_from_slice(&[1; 9]);
        assert!(decode::<Pair>(&long).unwrap_err().what.contains("left over"));
        let mut be = buf.clone();
        be[1] = 0;
        assert!(decode::<Pair>(&be).unwrap_err().what.contains("encapsulation"));
    }

    #[test]
    fn csv_cells_round_trip_floats_and_quote_text() {
        let mut s = String::new();
        0.1f64.csv(&mut s);
        f64::INFINITY.csv(&mut s);
        (-12i64).csv(&mut s);
        String::from("a \"b\"").csv(&mut s);
        assert_eq!(s, ",0.1,inf,-12,\"a \"\"b\"\"\"");
    }
}
