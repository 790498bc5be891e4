//! The property both fuzz harnesses check on one input.

use hap_core::protocol::{decode, encode, expected_len, MAX_FRAME_LEN};

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
