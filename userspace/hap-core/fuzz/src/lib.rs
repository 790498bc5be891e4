//! The property both fuzz harnesses check on one input.

use hap_core::protocol::{
    decode, encode, expected_len, seal_crc, CRC_LEN, MAGIC, MAX_FRAME_LEN, VERSION,
};

/// Decode `data`; it must not panic, and a frame it accepts must re-encode
/// to a frame that decodes to the same thing and has the advertised length.
pub fn check(data: &[u8]) {
    let _ = expected_len(data);
    if let Ok((h, f)) = decode(data) {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = encode(&h, &f, &mut buf);
        assert_eq!(n, data.len(), "accepted frame of the wrong length");
        assert_eq!(
            decode(&buf[..n]),
            Ok((h, f)),
            "decode/encode not a fixed point"
        );
    }
}

/// `data` with a valid magic, version and CRC-32C written over it (when it
/// is long enough to hold them), so that the fuzzer spends its time in the
/// header and payload checks behind the CRC instead of guessing checksums.
/// The type byte (offset 3) and everything else stay as the fuzzer chose.
pub fn with_valid_crc(data: &[u8]) -> Vec<u8> {
    let mut v = data.to_vec();
    if v.len() >= 4 + CRC_LEN {
        v[0] = MAGIC[0];
        v[1] = MAGIC[1];
        v[2] = VERSION;
        seal_crc(&mut v);
    }
    v
}
