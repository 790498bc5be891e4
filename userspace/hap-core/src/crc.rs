//! CRC-32C (Castagnoli), as used by iSCSI/SCTP/ext4: reflected polynomial
//! 0x82F63B78 (normal form 0x1EDC6F41), init 0xFFFF_FFFF, final xor
//! 0xFFFF_FFFF. Check value: `crc32c(b"123456789") == 0xE306_9283`.
//!
//! Table-driven, slicing-by-8: eight bytes per step through eight 1 KiB
//! tables (`SLICE[k]` is the CRC register after `k` more zero bytes), the
//! tail one byte per step through [`TABLE`]; the same CRC as the byte-wise
//! loop, bit for bit (tested against it). The tables are computed at
//! compile time. No panics: every table index is masked to 0..=255.

/// Reflected CRC-32C polynomial.
pub const POLY_REFLECTED: u32 = 0x82F6_3B78;

/// CRC-32C of `"123456789"`.
pub const CHECK: u32 = 0xE306_9283;

const fn make_table() -> [u32; 256] {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 {
                (c >> 1) ^ POLY_REFLECTED
            } else {
                c >> 1
            };
            k += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
}

/// The byte-wise lookup table.
pub static TABLE: [u32; 256] = make_table();

const fn make_slices() -> [[u32; 256]; 8] {
    let t0 = make_table();
    let mut s = [[0u32; 256]; 8];
    s[0] = t0;
    let mut k = 1;
    while k < 8 {
        let mut i = 0;
        while i < 256 {
            let prev = s[k - 1][i];
            s[k][i] = (prev >> 8) ^ t0[(prev & 0xFF) as usize];
            i += 1;
        }
        k += 1;
    }
    s
}

/// Slicing-by-8 tables: `SLICE[k][b]` is the register of byte `b` followed
/// by `k` zero bytes (`SLICE[0]` is [`TABLE`]).
static SLICE: [[u32; 256]; 8] = make_slices();

/// Byte-wise update (the reference for the sliced one).
#[cfg(test)]
const fn update_bytewise(mut c: u32, data: &[u8]) -> u32 {
    let mut i = 0;
    while i < data.len() {
        c = TABLE[((c ^ data[i] as u32) & 0xFF) as usize] ^ (c >> 8);
        i += 1;
    }
    c
}

/// Incremental CRC-32C.
#[derive(Clone, Copy, Debug)]
pub struct Crc32c {
    state: u32,
}

impl Default for Crc32c {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32c {
    pub const fn new() -> Self {
        Crc32c { state: 0xFFFF_FFFF }
    }

    /// Feed more bytes.
    pub fn update(&mut self, data: &[u8]) {
        let mut c = self.state;
        let mut chunks = data.chunks_exact(8);
        for w in &mut chunks {
            // `w` has 8 bytes (chunks_exact): the fallback is never taken
            // and leaves no panic path.
            let v = u64::from_le_bytes(w.try_into().unwrap_or([0u8; 8]));
            let lo = (v as u32) ^ c;
            let hi = (v >> 32) as u32;
            let [s0, s1, s2, s3, s4, s5, s6, s7] = &SLICE;
            c = s7[(lo & 0xFF) as usize]
                ^ s6[((lo >> 8) & 0xFF) as usize]
                ^ s5[((lo >> 16) & 0xFF) as usize]
                ^ s4[(lo >> 24) as usize]
                ^ s3[(hi & 0xFF) as usize]
                ^ s2[((hi >> 8) & 0xFF) as usize]
                ^ s1[((hi >> 16) & 0xFF) as usize]
                ^ s0[(hi >> 24) as usize];
        }
        for &b in chunks.remainder() {
            c = TABLE[((c ^ b as u32) & 0xFF) as usize] ^ (c >> 8);
        }
        self.state = c;
    }

    /// The CRC of everything fed so far.
    pub const fn finish(&self) -> u32 {
        self.state ^ 0xFFFF_FFFF
    }
}

/// CRC-32C of `data` in one call.
pub fn crc32c(data: &[u8]) -> u32 {
    let mut c = Crc32c::new();
    c.update(data);
    c.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value() {
        assert_eq!(crc32c(b"123456789"), CHECK);
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
    }

    #[test]
    fn empty_and_incremental() {
        assert_eq!(crc32c(b""), 0);
        let mut c = Crc32c::new();
        c.update(b"1234");
        c.update(b"56789");
        assert_eq!(c.finish(), CHECK);
    }

    #[test]
    fn sliced_equals_bytewise() {
        // Every length 0..=80 and every split point of a pseudo-random
        // buffer: the sliced update is the byte-wise one, bit for bit.
        let mut x: u32 = 0x1234_5678;
        let buf: [u8; 80] = core::array::from_fn(|_| {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (x >> 24) as u8
        });
        for n in 0..=buf.len() {
            let want = update_bytewise(0xFFFF_FFFF, &buf[..n]) ^ 0xFFFF_FFFF;
            assert_eq!(crc32c(&buf[..n]), want, "length {n}");
            for cut in 0..=n {
                let mut c = Crc32c::new();
                c.update(&buf[..cut]);
                c.update(&buf[cut..n]);
                assert_eq!(c.finish(), want, "length {n}, split at {cut}");
            }
        }
        assert_eq!(SLICE[0], TABLE);
    }

    #[test]
    fn known_vectors() {
        // RFC 3720 B.4: 32 bytes of zeros / ones.
        assert_eq!(crc32c(&[0u8; 32]), 0x8A91_36AA);
        assert_eq!(crc32c(&[0xFFu8; 32]), 0x62A8_AB43);
        let inc: [u8; 32] = core::array::from_fn(|i| i as u8);
        assert_eq!(crc32c(&inc), 0x46DD_794E);
    }
}
