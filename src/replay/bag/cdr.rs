//! OMG CDR (XCDR1), the encoding ROS 2 puts on the wire and rosbag2 stores in MCAP (`cdr`
//! message encoding): a 4-byte encapsulation header — `00 00` big-endian, `00 01`
//! little-endian, then two option bytes — and the payload, where every primitive is aligned to
//! its own size counted from the payload's first byte (not the message's). Strings are a `u32`
//! length that counts the trailing NUL, then the bytes; sequences a `u32` count, then the items.
//!
//! [`CdrReader`] never panics and never allocates more than the message holds: every length is
//! checked against the bytes left before it is used. [`CdrWriter`] is its mirror, for tests and
//! for writing bags.

use crate::replay::bag::error::MessageError;

/// Bytes before the payload: representation id (2) and options (2).
const ENCAPSULATION_LEN: usize = 4;

/// Reads primitives in order from one CDR-encoded message.
pub struct CdrReader<'a> {
    payload: &'a [u8],
    pos: usize,
    little_endian: bool,
}

impl<'a> CdrReader<'a> {
    /// Reads the encapsulation header; plain CDR in either byte order is accepted, XCDR2 and
    /// parameter lists (which ROS 2 does not use for these messages) are refused.
    pub fn new(message: &'a [u8]) -> Result<Self, MessageError> {
        let error = |found: String| MessageError {
            field: "encapsulation",
            expected: "a CDR header 00 00 (big-endian) or 00 01 (little-endian)".into(),
            found,
        };
        let Some((header, payload)) = message.split_first_chunk::<ENCAPSULATION_LEN>() else {
            return Err(error(format!("a message of {} byte(s)", message.len())));
        };
        let little_endian = match [header[0], header[1]] {
            [0, 0] => false,
            [0, 1] => true,
            id => return Err(error(format!("{:02x} {:02x}", id[0], id[1]))),
        };
        Ok(Self { payload, pos: 0, little_endian })
    }

    /// The next `n` bytes, after padding to `align`.
    fn take(
        &mut self,
        n: usize,
        align: usize,
        field: &'static str,
        what: &str,
    ) -> Result<&'a [u8], MessageError> {
        let start = self.pos.next_multiple_of(align);
        match start.checked_add(n).filter(|&end| end <= self.payload.len()) {
            Some(end) => {
                self.pos = end;
                Ok(&self.payload[start..end])
            }
            None => Err(MessageError {
                field,
                expected: what.into(),
                found: format!("the message ends after {} payload byte(s)", self.payload.len()),
            }),
        }
    }

    fn array<const N: usize>(&mut self, field: &'static str, what: &str) -> Result<[u8; N], MessageError> {
        let bytes = self.take(N, N, field, what)?;
        let mut out = [0; N];
        out.copy_from_slice(bytes);
        if !self.little_endian {
            out.reverse();
        }
        Ok(out)
    }

    pub fn u32(&mut self, field: &'static str) -> Result<u32, MessageError> {
        self.array(field, "a 4-byte unsigned integer").map(u32::from_le_bytes)
    }

    pub fn i32(&mut self, field: &'static str) -> Result<i32, MessageError> {
        self.array(field, "a 4-byte integer").map(i32::from_le_bytes)
    }

    pub fn f32(&mut self, field: &'static str) -> Result<f32, MessageError> {
        self.array(field, "a 4-byte float").map(f32::from_le_bytes)
    }

    pub fn f64(&mut self, field: &'static str) -> Result<f64, MessageError> {
        self.array(field, "an 8-byte float").map(f64::from_le_bytes)
    }

    /// A string; invalid UTF-8 is replaced (frame ids are only shown to the user).
    pub fn string(&mut self, field: &'static str) -> Result<String, MessageError> {
        let len = self.u32(field)? as usize;
        let bytes = self.take(len, 1, field, &format!("a string of {len} byte(s)"))?;
        let text = bytes.strip_suffix(&[0]).unwrap_or(bytes);
        Ok(String::from_utf8_lossy(text).into_owned())
    }

    /// A sequence of 4-byte floats.
    pub fn f32_sequence(&mut self, field: &'static str) -> Result<Vec<f32>, MessageError> {
        let count = self.u32(field)? as usize;
        let what = format!("{count} 4-byte float(s)");
        let bytes = self.take(count.saturating_mul(4), 4, field, &what)?;
        let order = if self.little_endian { f32::from_le_bytes } else { f32::from_be_bytes };
        Ok(bytes.chunks_exact(4).map(|b| order([b[0], b[1], b[2], b[3]])).collect())
    }

    /// Skips `count` 8-byte floats (fields the filter does not use, still checked to be there).
    pub fn skip_f64s(&mut self, count: usize, field: &'static str) -> Result<(), MessageError> {
        self.take(count.saturating_mul(8), 8, field, &format!("{count} 8-byte float(s)")).map(|_| ())
    }
}

/// Writes a CDR message in the order [`CdrReader`] reads it.
pub struct CdrWriter {
    bytes: Vec<u8>,
    little_endian: bool,
}

impl CdrWriter {
    pub fn new(little_endian: bool) -> Self {
        Self { bytes: vec![0, u8::from(little_endian), 0, 0], little_endian }
    }

    fn put<const N: usize>(&mut self, mut le_bytes: [u8; N]) {
        let payload_len = self.bytes.len() - ENCAPSULATION_LEN;
        self.bytes.resize(ENCAPSULATION_LEN + payload_len.next_multiple_of(N), 0);
        if !self.little_endian {
            le_bytes.reverse();
        }
        self.bytes.extend_from_slice(&le_bytes);
    }

    pub fn u32(&mut self, v: u32) {
        self.put(v.to_le_bytes());
    }

    pub fn i32(&mut self, v: i32) {
        self.put(v.to_le_bytes());
    }

    pub fn f32(&mut self, v: f32) {
        self.put(v.to_le_bytes());
    }

    pub fn f64(&mut self, v: f64) {
        self.put(v.to_le_bytes());
    }

    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.bytes.extend_from_slice(s.as_bytes());
        self.bytes.push(0);
    }

    pub fn f32_sequence(&mut self, values: &[f32]) {
        self.u32(values.len() as u32);
        values.iter().for_each(|&v| self.f32(v));
    }

    pub fn finish(self) -> Vec<u8> {
        self.bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cdr_reads_what_it_writes_in_both_byte_orders() {
        for little_endian in [true, false] {
            let mut w = CdrWriter::new(little_endian);
            w.string("laser");
            w.f64(-2.5);
            w.i32(-7);
            w.f32_sequence(&[1.0, f32::INFINITY, f32::NAN]);
            let bytes = w.finish();
            let mut r = CdrReader::new(&bytes).expect("header");
            assert_eq!(r.string("s").expect("string"), "laser");
            assert_eq!(r.f64("d").expect("f64"), -2.5);
            assert_eq!(r.i32("i").expect("i32"), -7);
            let seq = r.f32_sequence("q").expect("sequence");
            assert!(seq[0] == 1.0 && seq[1] == f32::INFINITY && seq[2].is_nan(), "{seq:?}");
        }
    }

    #[test]
    fn cdr_aligns_relative_to_the_payload_not_the_message() {
        // An empty string is 5 payload bytes (length 1, NUL), so the f64 starts at payload offset
        // 8 = message offset 12; aligning on the message offset would put it at 16.
        let mut w = CdrWriter::new(true);
        w.string("");
        w.f64(1.5);
        let bytes = w.finish();
        assert_eq!(bytes.len(), 4 + 8 + 8, "header, string padded to 8, f64");
        assert_eq!(&bytes[12..20], &1.5f64.to_le_bytes(), "the f64 sits at payload offset 8");
        let mut r = CdrReader::new(&bytes).expect("header");
        r.string("s").expect("string");
        assert_eq!(r.f64("d").expect("f64"), 1.5);
    }

    #[test]
    fn cdr_big_endian_bytes_are_read_big_endian() {
        let bytes = [0, 0, 0, 0, 0x40, 0x49, 0x0f, 0xdb]; // π as a big-endian f32
        let mut r = CdrReader::new(&bytes).expect("header");
        assert!((r.f32("pi").expect("f32") - std::f32::consts::PI).abs() < 1e-6);
    }

    #[test]
    fn cdr_errors_name_the_field_and_never_overread() {
        assert!(CdrReader::new(&[0, 1]).is_err(), "a message shorter than its header");
        let err = CdrReader::new(&[0, 7, 0, 0]).err().expect("XCDR2 is refused");
        assert_eq!(err.field, "encapsulation");
        assert!(err.found.contains("00 07"), "{err}");
        let mut w = CdrWriter::new(true);
        w.u32(u32::MAX); // a sequence count far beyond the message
        let bytes = w.finish();
        let err = CdrReader::new(&bytes).expect("header").f32_sequence("ranges").expect_err("too long");
        assert_eq!(err.field, "ranges");
        assert!(err.to_string().contains("4294967295 4-byte float(s)"), "{err}");
        let err = CdrReader::new(&bytes[..6]).expect("header").u32("count").expect_err("cut short");
        assert!(err.found.contains("2 payload byte(s)"), "{err}");
        let mut r = CdrReader::new(&bytes).expect("header");
        assert!(r.string("frame_id").is_err(), "a string length past the end is an error, not a panic");
    }
}
