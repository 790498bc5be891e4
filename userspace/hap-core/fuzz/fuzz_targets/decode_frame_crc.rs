//! The decoder behind a valid CRC: the input gets a correct magic, version
//! and CRC-32C (`with_valid_crc`), so mutations reach the type, length,
//! flag and payload checks.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    hap_core_fuzz::check(&hap_core_fuzz::with_valid_crc(data));
});
