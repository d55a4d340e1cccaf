//! A minimal CDR encoder: the subset ROS 2 uses for plain (non-XTypes) messages.
//!
//! The wire format is what `rmw_fastrtps`/`rmw_cyclonedds` produce for ROS 2 messages and
//! what rosbag2 stores:
//!
//! - a 4-byte encapsulation header `00 01 00 00` (plain CDR, little endian);
//! - every primitive aligned to its own size (up to 8), measured from the end of that header;
//! - `string`: u32 length counting the NUL terminator, the bytes, then the NUL;
//! - `T[]` (sequence): u32 element count, then the elements;
//! - `T[N]` (array): the N elements, no count;
//! - `bool` as one byte, 0 or 1.
//!
//! Only little endian output is produced, since every reader must handle it and ROS 2 writes
//! nothing else on the platforms that matter.

use crate::error::CdrError;

/// Encapsulation header for plain CDR, little endian (`CDR_LE`).
pub const ENCAPSULATION_CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Appends CDR-encoded values to a buffer that starts with the encapsulation header.
///
/// Use it to implement [`crate::RosMessage`] for message types this crate does not define:
/// call the methods in the `.msg` field order.
#[derive(Debug, Clone)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    /// A writer holding just the encapsulation header.
    pub fn new() -> Self {
        Self::with_capacity(64)
    }

    /// Like [`CdrWriter::new`], reserving room for `capacity` payload bytes up front (images).
    pub fn with_capacity(capacity: usize) -> Self {
        let mut buf = Vec::with_capacity(capacity.saturating_add(ENCAPSULATION_CDR_LE.len()));
        buf.extend_from_slice(&ENCAPSULATION_CDR_LE);
        Self { buf }
    }

    /// The encoded message, header included.
    pub fn into_bytes(self) -> Vec<u8> {
        self.buf
    }

    /// The encoded bytes so far, header included.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf
    }

    /// Pads with zeros so the next value starts at a multiple of `n` bytes after the header.
    fn align(&mut self, n: usize) {
        let pos = self.buf.len() - ENCAPSULATION_CDR_LE.len();
        let pad = (n - pos % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    pub fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }

    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    pub fn i8(&mut self, v: i8) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn u16(&mut self, v: u16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn i16(&mut self, v: i16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn u64(&mut self, v: u64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn i64(&mut self, v: i64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn f32(&mut self, v: f32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A `string` field. Refuses interior NULs (see [`CdrError::StringContainsNul`]).
    pub fn string(&mut self, s: &str) -> Result<(), CdrError> {
        let bytes = s.as_bytes();
        if let Some(offset) = bytes.iter().position(|&b| b == 0) {
            return Err(CdrError::StringContainsNul { len: bytes.len(), offset });
        }
        let len = bytes
            .len()
            .checked_add(1)
            .and_then(|n| u32::try_from(n).ok())
            .ok_or(CdrError::TooLong { what: "string", len: bytes.len() })?;
        self.u32(len);
        self.buf.extend_from_slice(bytes);
        self.buf.push(0);
        Ok(())
    }

    /// The u32 element count that opens a sequence (`T[]`); the caller writes the elements.
    pub fn sequence_len(&mut self, len: usize) -> Result<(), CdrError> {
        let n = u32::try_from(len).map_err(|_| CdrError::TooLong { what: "sequence", len })?;
        self.u32(n);
        Ok(())
    }

    /// A `uint8[]` / `byte[]` sequence, copied in one go (images).
    pub fn u8_seq(&mut self, v: &[u8]) -> Result<(), CdrError> {
        self.sequence_len(v.len())?;
        self.buf.extend_from_slice(v);
        Ok(())
    }

    /// A `float32[]` sequence.
    pub fn f32_seq(&mut self, v: &[f32]) -> Result<(), CdrError> {
        self.sequence_len(v.len())?;
        self.f32_array(v);
        Ok(())
    }

    /// A `float64[]` sequence.
    pub fn f64_seq(&mut self, v: &[f64]) -> Result<(), CdrError> {
        self.sequence_len(v.len())?;
        self.f64_array(v);
        Ok(())
    }

    /// A fixed `float32[N]` array: elements only, no count.
    pub fn f32_array(&mut self, v: &[f32]) {
        // The elements are contiguous once the first is aligned. No element, no padding: an
        // empty sequence must not shift the field after it.
        if v.is_empty() {
            return;
        }
        self.align(4);
        self.buf.reserve(v.len() * 4);
        for x in v {
            self.buf.extend_from_slice(&x.to_le_bytes());
        }
    }

    /// A fixed `float64[N]` array: elements only, no count.
    pub fn f64_array(&mut self, v: &[f64]) {
        if v.is_empty() {
            return;
        }
        self.align(8);
        self.buf.reserve(v.len() * 8);
        for x in v {
            self.buf.extend_from_slice(&x.to_le_bytes());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alignment_is_relative_to_the_end_of_the_header() {
        let mut w = CdrWriter::new();
        w.u8(7);
        w.f64(1.0);
        let b = w.into_bytes();
        // header, u8, 7 bytes of padding, then the f64 at payload offset 8
        assert_eq!(&b[..4], &ENCAPSULATION_CDR_LE);
        assert_eq!(b[4], 7);
        assert_eq!(&b[5..12], &[0; 7]);
        assert_eq!(&b[12..20], &1.0f64.to_le_bytes());
        assert_eq!(b.len(), 20);
    }

    #[test]
    fn strings_count_and_carry_the_terminator() {
        let mut w = CdrWriter::new();
        w.string("map").unwrap();
        w.string("").unwrap();
        assert_eq!(&w.into_bytes()[4..], &[4, 0, 0, 0, b'm', b'a', b'p', 0, 1, 0, 0, 0, 0]);
    }

    #[test]
    fn interior_nul_is_refused() {
        let mut w = CdrWriter::new();
        assert_eq!(w.string("a\0b"), Err(CdrError::StringContainsNul { len: 3, offset: 1 }));
    }

    #[test]
    fn header_then_f64_is_padded() {
        // std_msgs/Header {stamp {1, 2}, frame_id "a"} followed by a float64: the header ends
        // at payload offset 14, so the float64 starts at 16.
        let mut w = CdrWriter::new();
        w.i32(1);
        w.u32(2);
        w.string("a").unwrap();
        w.f64(0.5);
        let b = w.into_bytes();
        assert_eq!(&b[4..18], &[1, 0, 0, 0, 2, 0, 0, 0, 2, 0, 0, 0, b'a', 0]);
        assert_eq!(&b[18..20], &[0, 0]);
        assert_eq!(&b[20..28], &0.5f64.to_le_bytes());
    }

    #[test]
    fn empty_f64_sequence_adds_no_padding() {
        let mut w = CdrWriter::new();
        w.f64_seq(&[]).unwrap();
        w.u32(9);
        assert_eq!(&w.into_bytes()[4..], &[0, 0, 0, 0, 9, 0, 0, 0]);
    }

    #[test]
    fn sequences_carry_a_count_and_arrays_do_not() {
        let mut w = CdrWriter::new();
        w.f32_seq(&[1.0, 2.0]).unwrap();
        w.f64_array(&[3.0]);
        let b = w.into_bytes();
        assert_eq!(&b[4..8], &[2, 0, 0, 0]);
        assert_eq!(&b[8..12], &1.0f32.to_le_bytes());
        assert_eq!(&b[12..16], &2.0f32.to_le_bytes());
        // payload offset 12 -> padded to 16 for the f64
        assert_eq!(&b[16..20], &[0; 4]);
        assert_eq!(&b[20..28], &3.0f64.to_le_bytes());
    }
}
