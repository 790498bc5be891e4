// SPDX-License-Identifier: GPL-2.0

//! Reading a device's text at the file position, without a panic path: the
//! kernel's `IovIterDest::simple_read_from_buffer()` does the same with an
//! overflow-checked addition (correct, but a `core::panicking` reference in
//! every module function it is inlined into; see scripts/check-ko-symbols.sh).

use core::fmt::Write;
use kernel::{iov::IovIterDest, prelude::*};

/// Copy `contents[*ppos..]` to `iov` and advance `*ppos` by what was copied;
/// 0 at or past the end, `EINVAL` for a negative position.
pub(crate) fn read_at(iov: &mut IovIterDest<'_>, ppos: &mut i64, contents: &[u8]) -> Result<usize> {
    let pos = usize::try_from(*ppos).map_err(|_| EINVAL)?;
    let Some(rest) = contents.get(pos..) else {
        return Ok(0);
    };
    let n = iov.copy_to_iter(rest);
    *ppos = i64::try_from(pos.saturating_add(n)).unwrap_or(i64::MAX);
    Ok(n)
}

/// A fixed-capacity text buffer for `core::fmt` (no allocation while formatting).
pub(crate) struct TextBuf<const N: usize> {
    buf: [u8; N],
    len: usize,
}

impl<const N: usize> TextBuf<N> {
    pub(crate) fn new() -> Self {
        TextBuf {
            buf: [0; N],
            len: 0,
        }
    }

    pub(crate) fn as_bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }
}

impl<const N: usize> Write for TextBuf<N> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let free = self.buf.get_mut(self.len..).unwrap_or(&mut []);
        let mut n = 0usize;
        for (d, b) in free.iter_mut().zip(s.as_bytes()) {
            *d = *b;
            n = n.saturating_add(1);
        }
        self.len = self.len.saturating_add(n).min(N);
        if n < s.len() {
            Err(core::fmt::Error)
        } else {
            Ok(())
        }
    }
}
