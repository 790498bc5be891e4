//! The bridge's cost per frame, v2 against v1, on this host (a figure for
//! Documentation/performance.md; not a test):
//!
//!   cargo run --release -p hap-auth --example gate_cost [N]
//!
//! v1: hap-core's decoder on the received bytes (what `--insecure` does).
//! v2 in: tag check, window, v1 re-encoding and hap-core's decoder
//! (`Gate::inspect` + `Gate::commit`) of a `vpr_stream`; a forged one
//! (`inspect` only, refused at the tag). v2 out: sealing an `answer` read
//! from the kernel (`Gate::seal_from_kernel`).

use std::hint::black_box;
use std::time::Instant;

use hap_auth::*;
use hap_core::fixed::{Pose, Twist};
use hap_core::protocol::{decode, encode, Answer, Frame, FrameHeader, HEADER_LEN, MAX_FRAME_LEN};

/// Where a proof's client nonce starts (a flipped bit there: another cookie).
const HEADER_LEN_V: usize = HEADER_LEN + NONCE_LEN;

fn per_frame(n: u32, mut f: impl FnMut(u32)) -> f64 {
    for i in 0..n / 10 {
        f(i);
    }
    let t = Instant::now();
    for i in 0..n {
        f(i);
    }
    t.elapsed().as_nanos() as f64 / f64::from(n)
}

fn main() {
    let n: u32 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(200_000);
    let vpr = Frame::VprStream {
        pose: Pose::default(),
        twist: Twist::default(),
    };
    let h = |seq| FrameHeader {
        control: 0,
        session: 1,
        seq,
        timestamp_us: seq,
    };
    // v1.
    let mut b = [0u8; MAX_FRAME_LEN];
    let len = encode(&h(1), &vpr, &mut b);
    let v1 = per_frame(n, |_| {
        black_box(decode(black_box(&b[..len])).is_ok());
    });
    // v2: a gate with a session (kernel session 1).
    let mut gate = Gate::new(Psk::test_key(), &[7; 32]);
    let mut c = ClientAuth::new(Psk::test_key());
    let src = std::net::SocketAddr::from(([127, 0, 0, 1], 4000));
    let now = std::time::Duration::from_secs(10);
    let open = c.hello(&h(0), [1; NONCE_LEN]);
    let i = gate.inspect(open.bytes(), src, now).unwrap();
    if let Action::Challenge(cookie) = gate.commit(&i, now) {
        c.open(cookie.bytes()).unwrap();
    }
    let proof = c.prove(&h(0)).unwrap();
    let i = gate.inspect(proof.bytes(), src, now).unwrap();
    let _ = gate.commit(&i, now);
    let mut ack = [0u8; MAX_FRAME_LEN];
    let al = encode(
        &FrameHeader { session: 1, ..h(1) },
        &Frame::SessionAck {
            client_nonce: 1,
            period_us: 1000,
        },
        &mut ack,
    );
    let sa = gate.seal_from_kernel(&ack[..al]).unwrap();
    c.open(sa.bytes()).unwrap();
    let frames: Vec<Wire> = (1..=n + n / 10)
        .map(|s| c.seal(&h(s), &vpr).unwrap())
        .collect();
    let mut k = 0usize;
    let v2_in = per_frame(n, |_| {
        let w = &frames[k];
        k += 1;
        let i = gate.inspect(black_box(w.bytes()), src, now).unwrap();
        black_box(gate.commit(&i, now));
    });
    // A forged frame newer than the window: refused at its tag (one HMAC).
    let mut forged = c.seal(&h(10 * n), &vpr).unwrap();
    forged.buf[forged.len - 1] ^= 1;
    let v2_forged = per_frame(n, |_| {
        black_box(gate.inspect(black_box(forged.bytes()), src, now).is_err());
    });
    // The handshake's frames from strangers: a forged open_session (its
    // tag), a forged open_proof with a live epoch (the cookie, one HMAC
    // under the bridge's secret), a recorded open_session replayed from
    // another address (its tag, then the nonce memory), and a key holder's
    // open_session answered with a cookie.
    let mut forged_hello = c.hello(&h(0), [9; NONCE_LEN]);
    forged_hello.buf[forged_hello.len - 1] ^= 1;
    let hello_forged = per_frame(n, |_| {
        black_box(
            gate.inspect(black_box(forged_hello.bytes()), src, now)
                .is_err(),
        );
    });
    let mut forged_proof = proof;
    forged_proof.buf[HEADER_LEN_V] ^= 1;
    let proof_forged = per_frame(n, |_| {
        black_box(
            gate.inspect(black_box(forged_proof.bytes()), src, now)
                .is_err(),
        );
    });
    let other = std::net::SocketAddr::from(([127, 0, 0, 2], 4000));
    let hello_replayed = per_frame(n, |_| {
        black_box(gate.inspect(black_box(open.bytes()), other, now).is_err());
    });
    let mut fresh = 0u32;
    let cookie = per_frame(n, |k| {
        fresh += 1;
        let mut nc = [3u8; NONCE_LEN];
        nc[..4].copy_from_slice(&fresh.to_be_bytes());
        let o = seal_open(&Psk::test_key(), &FrameHeader { session: 0, ..h(k) }, &nc);
        let i = gate.inspect(black_box(o.bytes()), src, now).unwrap();
        black_box(gate.commit(&i, now));
    });
    let mut ans = [0u8; MAX_FRAME_LEN];
    let anl = encode(&h(7), &Frame::Answer(Answer::default()), &mut ans);
    let v2_out = per_frame(n, |_| {
        black_box(gate.seal_from_kernel(black_box(&ans[..anl])));
    });
    let client_seal = per_frame(n, |s| {
        black_box(c.seal(&h(s), &vpr));
    });
    println!(
        "frames: {n} per figure (one thread; hap-auth and the hash optimised in every profile)"
    );
    println!("v1 vpr_stream in (decode):                 {v1:8.0} ns/frame");
    println!("v2 vpr_stream in (verify+window+v1+decode): {v2_in:8.0} ns/frame");
    println!("v2 forged vpr_stream (refused at the tag):  {v2_forged:8.0} ns/frame");
    println!("v2 answer out (decode + seal):              {v2_out:8.0} ns/frame");
    println!("client: seal a vpr_stream:                  {client_seal:8.0} ns/frame");
    println!("forged open_session (refused at the tag):   {hello_forged:8.0} ns/frame");
    println!("forged open_proof (refused at the cookie):  {proof_forged:8.0} ns/frame");
    println!("recorded open_session from elsewhere:       {hello_replayed:8.0} ns/frame");
    println!("open_session answered with a cookie:        {cookie:8.0} ns/frame");
}
