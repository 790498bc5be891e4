//! The library against the fake controller (hap-core frames over UDP).

use std::time::Duration;

use virtuose_api::fake_peer::{FakePeer, FakePeerConfig};
use virtuose_api::{CommandType, IndexingMode, Options, VirtContext, VirtError};

/// Short time-outs, with room for a loaded host: an OpenSession waits
/// 100, 200, then 400 ms.
fn quick() -> Options {
    Options {
        reply_timeout: Duration::from_millis(100),
        attempts: 3,
        ..Options::default()
    }
}

/// Stream a point mass coupled to the handle for `steps` ms; returns the
/// final handle and object positions.
fn run_coupling(vc: &mut VirtContext, steps: usize) -> ([f32; 7], [f32; 7]) {
    let (dt, mass) = (0.001f32, 0.2f32);
    let mut pos = [0.0f32, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    let mut speed = [0.0f32; 6];
    let mut handle = [0.0f32; 7];
    for _ in 0..steps {
        vc.set_speed(&speed).unwrap();
        vc.set_position(&pos).unwrap();
        vc.wait_answer(Duration::from_millis(20));
        let (Ok(h), Ok(f)) = (vc.get_position(), vc.get_force()) else {
            continue;
        };
        handle = h;
        for k in 0..3 {
            speed[k] += f[k] / mass * dt;
            speed[k] *= 0.995;
            pos[k] += speed[k] * dt;
        }
    }
    (handle, pos)
}

fn dist(a: &[f32; 7], b: &[f32; 7]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[test]
fn session_configuration_and_coupling() {
    let peer = FakePeer::start(FakePeerConfig::default()).unwrap();
    let mut vc = VirtContext::open_with(&peer.address(), quick()).unwrap();
    assert_ne!(vc.session_id(), 0);
    assert_eq!(vc.get_position(), Err(VirtError::NoData));

    vc.set_time_step(0.001).unwrap();
    vc.set_base_frame(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        .unwrap();
    vc.set_observation_frame(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        .unwrap();
    vc.set_force_factor(1.0).unwrap();
    vc.set_speed_factor(1.0).unwrap();
    vc.set_indexing_mode(IndexingMode::All).unwrap();
    vc.set_command_type(CommandType::VirtMech).unwrap();
    vc.attach_vo(0.2, [0.001; 3]).unwrap();
    vc.set_power_on(true).unwrap();

    let (handle, obj) = run_coupling(&mut vc, 1500);
    let d = dist(&handle, &obj);
    assert!(
        d < 0.02,
        "object did not follow the handle: {handle:?} vs {obj:?}"
    );
    assert!(
        handle[0].abs() > 1e-4 || handle[2].abs() > 1e-4,
        "handle did not move"
    );
    assert!(vc.get_power_on().unwrap());
    assert!(vc.get_dead_man().unwrap());
    assert!(!vc.get_emergency_stop().unwrap());
    assert_eq!(vc.get_alarm().unwrap(), 0);
    let sp = vc.get_speed().unwrap();
    assert!(sp.iter().any(|v| *v != 0.0), "no AnswerTwist seen");

    let ls = vc.link_stats();
    println!("link: {ls:?}");
    assert!(ls.answers > 1000, "{ls:?}");
    assert_eq!(ls.lost, 0);
    assert_eq!(ls.period_us, 1000);
    assert!(ls.rtt_ms_mean > 0.0 && ls.rtt_ms_mean < 50.0, "{ls:?}");
    assert!(ls.rate_hz > 100.0, "{ls:?}");
    vc.close().unwrap();
    assert_eq!(vc.get_force(), Err(VirtError::Closed));
    vc.close().unwrap(); // idempotent

    let st = peer.stats();
    assert_eq!(st.frames.get("close_session"), Some(&1));
    assert!(st.frames.get("vpr_stream").copied().unwrap_or(0) >= 1500);
    assert!(st.client.is_none());
}

#[test]
fn loss_and_duplicates_are_measured() {
    let peer = FakePeer::start(FakePeerConfig {
        drop_every: 10,
        duplicate_every: 7,
        twist_every: 0,
        ..Default::default()
    })
    .unwrap();
    let vc = VirtContext::open_with(&peer.address(), quick()).unwrap();
    for _ in 0..500 {
        vc.set_position(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
            .unwrap();
        vc.wait_answer(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(50));
    let ls = vc.link_stats();
    println!("link: {ls:?}");
    assert!((45..=55).contains(&ls.lost), "{ls:?}");
    assert!(ls.duplicates >= 50, "{ls:?}");
    assert!(ls.loss_ratio > 0.08 && ls.loss_ratio < 0.12, "{ls:?}");
}

#[test]
fn round_trips_are_recorded_per_sample() {
    let peer = FakePeer::start(FakePeerConfig::default()).unwrap();
    let vc = VirtContext::open_with(&peer.address(), quick()).unwrap();
    let mut got = Vec::new();
    vc.drain_rtt(&mut got);
    assert!(got.is_empty(), "nothing recorded before record_rtt(true)");
    vc.record_rtt(true);
    for i in 0..200 {
        vc.set_position(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
            .unwrap();
        vc.wait_answer(Duration::from_millis(5));
        if i == 50 {
            // Acks share the controller's sequence counter with the
            // answers: they must not be counted as lost answers.
            vc.set_power_on(true).unwrap();
            vc.set_time_step(0.001).unwrap();
        }
    }
    std::thread::sleep(Duration::from_millis(50));
    vc.drain_rtt(&mut got);
    let ls = vc.link_stats();
    assert!(!got.is_empty(), "no round trip recorded: {ls:?}");
    assert!(got.len() as u64 <= ls.vpr_sent, "{} > {ls:?}", got.len());
    // Each VprStream is echoed at most once, in order, with a sane RTT.
    assert!(
        got.windows(2).all(|w| w[1].vpr_seq > w[0].vpr_seq),
        "{got:?}"
    );
    assert!(got.iter().all(|s| s.rtt_us < 1_000_000), "{got:?}");
    let max_us = got.iter().map(|s| s.rtt_us).max().unwrap() as f64;
    assert!(
        (max_us / 1e3 - ls.rtt_ms_max).abs() < 0.01,
        "{max_us} vs {ls:?}"
    );
    let n = got.len();
    vc.drain_rtt(&mut got);
    assert_eq!(got.len(), n, "a second drain adds nothing new");
    assert_eq!(vc.rtt_overflow(), 0);
    assert_eq!(ls.lost, 0, "{ls:?}");
    vc.record_rtt(false);
}

#[test]
fn second_client_is_refused_and_times_out() {
    let peer = FakePeer::start(FakePeerConfig::default()).unwrap();
    let _first = VirtContext::open_with(&peer.address(), quick()).unwrap();
    let second = VirtContext::open_with(&peer.address(), quick());
    assert!(
        matches!(second, Err(VirtError::Timeout("open_session"))),
        "{:?}",
        second.err()
    );
    assert!(peer.stats().stray >= 1);
}

#[test]
fn silent_controller_times_out_and_bad_arguments_are_refused() {
    let silent = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let addr = format!("127.0.0.1#{}", silent.local_addr().unwrap().port());
    let t = std::time::Instant::now();
    let r = VirtContext::open_with(&addr, quick());
    assert!(matches!(r, Err(VirtError::Timeout(_))));
    assert!(t.elapsed() < Duration::from_secs(2));
    assert!(matches!(
        VirtContext::open("no port#x"),
        Err(VirtError::InvalidAddress(_))
    ));

    let peer = FakePeer::start(FakePeerConfig::default()).unwrap();
    let mut vc = VirtContext::open_with(&peer.address(), quick()).unwrap();
    assert!(matches!(
        vc.set_time_step(0.0),
        Err(VirtError::InvalidArgument(_))
    ));
    assert!(matches!(
        vc.set_force_factor(-1.0),
        Err(VirtError::InvalidArgument(_))
    ));
    assert!(matches!(
        vc.attach_vo(f32::NAN, [0.0; 3]),
        Err(VirtError::InvalidArgument(_))
    ));
    assert!(matches!(
        vc.set_position(&[0.0; 7]),
        Err(VirtError::InvalidArgument(_))
    ));
    assert!(matches!(
        vc.set_speed(&[f32::NAN; 6]),
        Err(VirtError::InvalidArgument(_))
    ));
    let e = vc.set_time_step(2.0).unwrap_err();
    assert!(e.to_string().contains("time step"), "{e}");
}

/// With `link_passivity`, a controller that grants no energy (the fake
/// one's `answer_twist` carries 0) never gets to push the object along its
/// motion: `get_force` takes that part off; the same run without the
/// option is pushed. The force against the motion goes through, and what
/// the object put in is granted back on the next `vpr_stream`.
#[test]
fn link_passivity_pushes_the_object_only_with_granted_energy() {
    let peer = FakePeer::start(FakePeerConfig {
        answer_every_period: true,
        twist_every: 4,
        amplitude: [0.0; 3],
        ..FakePeerConfig::default()
    })
    .unwrap();
    let dt = 0.001f32;
    // Off; on through `Options`; on through the address (as from C's
    // `virtOpen("host#port?link=passive")`).
    for (link_passivity, suffix) in [(false, ""), (true, ""), (false, "?link=passive")] {
        let mut vc = VirtContext::open_with(
            &format!("{}{suffix}", peer.address()),
            Options {
                link_passivity,
                ..quick()
            },
        )
        .unwrap();
        let link_passivity = link_passivity || !suffix.is_empty();
        vc.set_time_step(dt).unwrap();
        vc.set_command_type(CommandType::VirtMech).unwrap();
        vc.attach_vo(0.2, [0.001; 3]).unwrap();
        vc.set_power_on(true).unwrap();
        // The object 5 cm from the handle: the spring pulls it back.
        let pos = [0.05f32, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let (mut along, mut against) = (0.0f64, 0.0f64);
        for k in 0..300 {
            // Moving toward the handle (along the pull), then away.
            let v = if k < 150 { -0.1f32 } else { 0.1 };
            vc.set_speed(&[v, 0.0, 0.0, 0.0, 0.0, 0.0]).unwrap();
            vc.set_position(&pos).unwrap();
            vc.wait_answer(Duration::from_millis(20));
            let Ok(f) = vc.get_force() else { continue };
            let p = f64::from(f[0]) * f64::from(v) * f64::from(dt);
            if k < 150 {
                along += p;
            } else {
                against += p;
            }
        }
        let ledger = vc.link_ledger();
        if link_passivity {
            assert!(along <= 1e-6, "pushed along the motion: {along} J");
            assert!(against < -1e-3, "no force against the motion: {against} J");
            assert!(ledger.energy_in.to_f64() > 1e-3, "{ledger:?}");
            assert_eq!(ledger.granted, ledger.energy_in.sub_sat(ledger.energy_out));
        } else {
            assert!(along > 1e-3, "the plain run was not pushed: {along} J");
        }
        vc.close().unwrap();
    }
}
