//! Classify a datagram with hap-core's decoder (no second parser here).

use hap_core::protocol::{decode, DecodeError, Frame, MAX_FRAME_LEN, MIN_FRAME_LEN};

use crate::session::{FrameKind, Reject};

/// Largest frame (spec §3.3.1.1: 90 bytes).
pub const MAX_FRAME: usize = MAX_FRAME_LEN;
/// Smallest frame (header + CRC).
pub const MIN_FRAME: usize = MIN_FRAME_LEN;

/// Validate a datagram and say what it is. Only whole, valid client →
/// controller frames are forwarded; answer-type frames coming from the
/// network are refused as malformed.
pub fn classify(data: &[u8]) -> Result<FrameKind, Reject> {
    if data.len() > MAX_FRAME {
        return Err(Reject::Oversize);
    }
    if data.len() < MIN_FRAME {
        return Err(Reject::Undersize);
    }
    match decode(data) {
        Err(DecodeError::TooLong) => Err(Reject::Oversize),
        Err(DecodeError::TooShort) => Err(Reject::Undersize),
        Err(_) => Err(Reject::Malformed),
        Ok((_, f)) if !f.frame_type().is_request() => Err(Reject::Malformed),
        Ok((_, Frame::OpenSession { .. })) => Ok(FrameKind::OpenSession),
        Ok((_, Frame::CloseSession)) => Ok(FrameKind::CloseSession),
        Ok(_) => Ok(FrameKind::Other),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hap_core::protocol::{encode, FrameHeader};

    fn enc(f: &Frame) -> Vec<u8> {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = encode(&FrameHeader::default(), f, &mut buf);
        buf[..n].to_vec()
    }

    #[test]
    fn classifies() {
        assert_eq!(
            classify(&enc(&Frame::OpenSession { client_nonce: 3 })),
            Ok(FrameKind::OpenSession)
        );
        assert_eq!(
            classify(&enc(&Frame::CloseSession)),
            Ok(FrameKind::CloseSession)
        );
        assert_eq!(
            classify(&enc(&Frame::PowerRequest(true))),
            Ok(FrameKind::Other)
        );
        assert_eq!(classify(&[0u8; 91]), Err(Reject::Oversize));
        assert_eq!(classify(&[0u8; 3]), Err(Reject::Undersize));
        assert_eq!(classify(&[0u8; 40]), Err(Reject::Malformed));
        let mut bad = enc(&Frame::PowerRequest(true));
        bad[17] ^= 1;
        assert_eq!(classify(&bad), Err(Reject::Malformed));
        let ack = enc(&Frame::SessionAck {
            client_nonce: 1,
            period_us: 1000,
        });
        assert_eq!(classify(&ack), Err(Reject::Malformed));
    }
}
