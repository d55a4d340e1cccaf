//! CSV text with every line ending made `\n`. The `csv` reader numbers lines by `\n`
//! alone: a file saved with `\r\n` endings had every error one line early, and one with
//! lone `\r` endings (old Mac exports) had every row on line 1.

use std::io::Read;

/// `inner`'s bytes with `\r\n` and a lone `\r` read as `\n`.
pub struct LfLineEnds<R> {
    inner: R,
    /// The last byte read was `\r`: a `\n` right after it ends the same line.
    after_cr: bool,
}

impl<R: Read> LfLineEnds<R> {
    pub fn new(inner: R) -> Self {
        LfLineEnds { inner, after_cr: false }
    }
}

impl<R: Read> Read for LfLineEnds<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        loop {
            let n = self.inner.read(buf)?;
            if n == 0 {
                return Ok(0);
            }
            let mut kept = 0;
            for k in 0..n {
                let b = buf[k];
                if b == b'\n' && self.after_cr {
                    self.after_cr = false;
                    continue;
                }
                self.after_cr = b == b'\r';
                buf[kept] = if b == b'\r' { b'\n' } else { b };
                kept += 1;
            }
            // A read that was one `\n` after a `\r` gives nothing: read on, as 0 means the end.
            if kept > 0 {
                return Ok(kept);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every ending reads as `\n`, whatever the reads' sizes split (`\r` and `\n` of one
    /// ending in two reads included), and the `csv` reader then numbers lines right.
    #[test]
    fn endings_read_as_newlines_and_lines_are_numbered_right() {
        let text = b"t,x\r\n1,2\r\n3,4\r5,6\n\r\n7,8\r";
        /// Gives its bytes `step` at a time.
        struct Trickle<'a>(&'a [u8], usize);
        impl Read for Trickle<'_> {
            fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
                let n = self.1.min(self.0.len()).min(buf.len());
                buf[..n].copy_from_slice(&self.0[..n]);
                self.0 = &self.0[n..];
                Ok(n)
            }
        }
        for step in 1..=text.len() {
            let mut out = Vec::new();
            LfLineEnds::new(Trickle(text, step)).read_to_end(&mut out).unwrap();
            assert_eq!(out, b"t,x\n1,2\n3,4\n5,6\n\n7,8\n", "reads of {step}");
        }
        let lines = |text: &[u8]| -> Vec<u64> {
            let mut reader = csv::ReaderBuilder::new().from_reader(LfLineEnds::new(text));
            reader.records().map(|r| r.unwrap().position().unwrap().line()).collect()
        };
        assert_eq!(lines(b"t,x\n1,2\n3,4\n"), [2, 3]);
        assert_eq!(lines(b"t,x\r\n1,2\r\n3,4\r\n"), [2, 3]);
        assert_eq!(lines(b"t,x\r1,2\r3,4\r"), [2, 3]);
    }
}
