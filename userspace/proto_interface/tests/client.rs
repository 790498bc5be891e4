//! The whole userspace chain on the host: virtuose_api (the client library)
//! → the proto_interface binary (named pipes for devices) → hap-core's
//! PROTO_IN as the kernel, which also answers every few milliseconds as
//! SERVO would. The key holder opens, configures, streams and closes; a
//! keyless client and a client with another key get nothing; forged frames
//! sent meanwhile from the client's own socket never reach PROTO_IN.

use std::ffi::CString;
use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::UdpSocket;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use hap_auth::Psk;
use hap_core::proto_in::ProtoIn;
use hap_core::protocol::{encode, expected_len, Answer, Frame, FrameHeader, MAX_FRAME_LEN};
use virtuose_api::{CommandType, Options, VirtContext, VirtError};

fn mkfifo(p: &Path) {
    let c = CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

fn quick(key: Option<Psk>) -> Options {
    Options {
        reply_timeout: Duration::from_millis(200),
        attempts: 3,
        key,
        ..Options::default()
    }
}

/// The key holder's options: a reply time-out long enough that a loaded
/// host never makes it retry the handshake (a retried handshake is a second
/// session, which the count below would see).
fn patient(key: Option<Psk>) -> Options {
    Options {
        reply_timeout: Duration::from_secs(10),
        ..quick(key)
    }
}

#[test]
fn the_client_library_through_the_bridge() {
    let dir = std::env::temp_dir().join(format!("proto_chain_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let key = dir.join("hap.key");
    let psk = Psk::generate().unwrap();
    psk.write_new(&key).unwrap();
    let (rin, rout) = (dir.join("rtf_in"), dir.join("rtf_out"));
    mkfifo(&rin);
    mkfifo(&rout);
    let mut child = Command::new(env!("CARGO_BIN_EXE_proto_interface"))
        .args([
            "--bind",
            "127.0.0.1",
            "--port",
            "0",
            "--print-addr",
            "--no-stats-file",
            // Not about expiry (the bridge's own tests are): a loaded host
            // that stalls this process for seconds must not end the session.
            "--session-timeout-ms",
            "60000",
        ])
        .arg("--key")
        .arg(&key)
        .arg("--rtf-in")
        .arg(&rin)
        .arg("--rtf-out")
        .arg(&rout)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let port = line.trim().rsplit(':').next().unwrap().to_string();
    let addr = format!("127.0.0.1#{port}");

    // The kernel: PROTO_IN on rtf_in; replies and an answer every 2 ms on rtf_out.
    let kernel = Arc::new(Mutex::new(ProtoIn::new()));
    let received: Arc<Mutex<Vec<Vec<u8>>>> = Arc::default();
    let stop = Arc::new(AtomicBool::new(false));
    let out = Arc::new(Mutex::new(
        File::options()
            .write(true)
            .open(&rout)
            .unwrap_or_else(|e| panic!("{e}")),
    ));
    let seq = Arc::new(Mutex::new(0u32));
    let send = {
        let (out, seq) = (out.clone(), seq.clone());
        move |session: u16, f: &Frame| {
            let mut s = seq.lock().unwrap();
            *s += 1;
            let h = FrameHeader {
                control: 0,
                session,
                seq: *s,
                timestamp_us: *s,
            };
            let mut b = [0u8; MAX_FRAME_LEN];
            let n = encode(&h, f, &mut b);
            let _ = out.lock().unwrap().write_all(&b[..n]);
        }
    };
    {
        let (kernel, received, send) = (kernel.clone(), received.clone(), send.clone());
        std::thread::spawn(move || {
            let mut f = File::open(rin).unwrap();
            let mut acc = Vec::new();
            let mut buf = [0u8; 4096];
            loop {
                let n = match f.read(&mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                acc.extend_from_slice(&buf[..n]);
                while acc.len() >= 4 {
                    let len = expected_len(&acc).expect("a v1 frame");
                    if acc.len() < len {
                        break;
                    }
                    let fr: Vec<u8> = acc.drain(..len).collect();
                    let mut k = kernel.lock().unwrap();
                    let o = k.handle(&fr, 0, 2000);
                    let session = k.session();
                    drop(k);
                    received.lock().unwrap().push(fr);
                    if let Some(r) = o.reply {
                        send(session, &r);
                    }
                }
            }
        });
    }
    {
        let (kernel, stop) = (kernel.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut cycle = 0u32;
            while !stop.load(Ordering::SeqCst) {
                std::thread::sleep(Duration::from_millis(2));
                cycle += 1;
                let (session, vpr_seq) = {
                    let k = kernel.lock().unwrap();
                    (k.session(), k.vpr().seq)
                };
                if session != 0 {
                    send(
                        session,
                        &Frame::Answer(Answer {
                            cycle,
                            vpr_seq,
                            ..Answer::default()
                        }),
                    );
                }
            }
        });
    }

    // A client without a key, and one with another key: nothing.
    if std::env::var_os(virtuose_api::KEY_ENV).is_none() {
        let e = VirtContext::open_with(&addr, quick(None));
        assert!(matches!(e, Err(VirtError::Timeout(_))), "{:?}", e.err());
    }
    let mut other = *psk.as_bytes();
    other[9] ^= 4;
    let e = VirtContext::open_with(&addr, quick(Some(Psk::from_bytes(other))));
    assert!(matches!(e, Err(VirtError::Timeout(_))), "{:?}", e.err());
    assert!(
        received.lock().unwrap().is_empty(),
        "a stranger reached PROTO_IN"
    );

    // The key holder, through the address string as from C's virtOpen.
    let url = format!("{addr}?key={}", key.display());
    let mut vc = VirtContext::open_with(&url, patient(None)).unwrap();
    assert!(vc.authenticated());
    vc.set_command_type(CommandType::Impedance).unwrap();
    vc.set_power_on(true).unwrap();
    // Forged frames (right length and layout, guessed session id, made-up
    // tags) while the client streams.
    let forger = UdpSocket::bind("127.0.0.1:0").unwrap();
    for i in 0..200u32 {
        vc.set_position(&[0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
            .unwrap();
        let mut f = [0u8; 84];
        f[..4].copy_from_slice(&[0x48, 0x43, 2, 0x0C]);
        f[6..8].copy_from_slice(&vc.session_id().to_be_bytes());
        f[8..12].copy_from_slice(&(100_000 + i).to_be_bytes());
        f[40] = 0x3f;
        f[41] = 0x80;
        for (k, b) in f[68..].iter_mut().enumerate() {
            *b = (i as u8).wrapping_mul(31).wrapping_add(k as u8);
        }
        forger.send_to(&f, format!("127.0.0.1:{port}")).unwrap();
        std::thread::sleep(Duration::from_millis(1));
    }
    assert!(vc.wait_answer(Duration::from_secs(1)));
    let ls = vc.link_stats();
    assert!(ls.answers > 10, "{ls:?}");
    assert_eq!(ls.decode_errors, 0, "{ls:?}");
    assert!(kernel.lock().unwrap().vpr().valid);
    vc.close().unwrap();
    std::thread::sleep(Duration::from_millis(200));
    stop.store(true, Ordering::SeqCst);
    // Everything PROTO_IN received was the key holder's: one session, no
    // rejects, every VPr frame the client sent and nothing else.
    let k = kernel.lock().unwrap();
    let c = k.counters();
    assert_eq!(c.sessions_opened, 1);
    assert_eq!(c.rejected_total(), 0);
    assert_eq!(c.vpr_frames, ls.vpr_sent, "{c:?} {ls:?}");
    assert_eq!(k.session(), 0, "closed");
    drop(k);
    let _ = child.kill();
    let _ = child.wait();
    let _ = std::fs::remove_dir_all(&dir);
}
