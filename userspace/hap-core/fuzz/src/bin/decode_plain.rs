//! Plain (no libFuzzer) harness: with file arguments, runs each file
//! through the check; otherwise runs N (default 1_000_000) pseudo-random
//! inputs, half of them valid frames with random mutations and a fixed CRC.

use hap_core::protocol::{seal_crc, FrameType, MAGIC, VERSION};

fn xorshift(s: &mut u64) -> u64 {
    *s ^= *s << 13;
    *s ^= *s >> 7;
    *s ^= *s << 17;
    *s
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let Some(first) = args.first() {
        if first.parse::<u64>().is_err() {
            for path in &args {
                let data = std::fs::read(path).expect("read input");
                hap_core_fuzz::check(&data);
            }
            println!("{} inputs ok", args.len());
            return;
        }
    }
    let n: u64 = args
        .first()
        .and_then(|a| a.parse().ok())
        .unwrap_or(1_000_000);
    let mut s = 0x2545_F491_4F6C_DD1Du64;
    for i in 0..n {
        let r = xorshift(&mut s);
        let len = (r % 100) as usize;
        let mut data: Vec<u8> = (0..len).map(|_| xorshift(&mut s) as u8).collect();
        if i % 2 == 0 && len >= 4 {
            let ty = FrameType::ALL[(r >> 8) as usize % FrameType::ALL.len()];
            data.resize(ty.frame_len(), 0);
            data[0] = MAGIC[0];
            data[1] = MAGIC[1];
            data[2] = VERSION;
            data[3] = ty as u8;
            if r & (1 << 20) != 0 {
                data[4] = 0;
                data[5] = 0;
            }
            seal_crc(&mut data);
        }
        hap_core_fuzz::check(&data);
    }
    println!("{n} inputs ok");
}
