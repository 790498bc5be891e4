//! The node as a process: its command line refuses bad arguments with a
//! message (no panic), and, connected to the fake controller, it powers the
//! arm on when a ROS 2 client calls its `set_power` service (std_srvs/SetBool)
//! and reports it on its reliable `status` topic, and it sets the command
//! type when a client sets its `command_type` parameter (rcl_interfaces'
//! set_parameters service), refusing an unknown one; when the controller
//! stops answering, the status turns STALE. The client is a second
//! ros2-client participant (DDS domain 43, loopback only); the independent
//! DDS peer is tests/ros2/run.sh.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use hapticctrl_ros2::msgs::{self, DiagnosticStatus, MsgType, SetBoolRequest, SetBoolResponse};
use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::rcl_interfaces::{SetParametersRequest, SetParametersResponse};
use ros2_client::{
    Context, Name, NodeName, NodeOptions, Parameter, ParameterValue, QosProfile, ServiceMapping,
    ServiceTypeName,
};
use rustdds::DomainParticipantBuilder;
use virtuose_api::fake_peer::{FakePeer, FakePeerConfig};

const NODE: &str = env!("CARGO_BIN_EXE_hapticctrl-ros2");
const DOMAIN: u16 = 43;

fn run_node(args: &[&str]) -> (i32, String) {
    let out = Command::new(NODE)
        .args(args)
        .env_remove("ROS_DOMAIN_ID")
        .output()
        .expect("node runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn bad_arguments_get_a_message() {
    for (args, needle) in [
        (vec!["--rate=-5"], "--rate -5"),
        (vec!["--rate", "nan"], "--rate NaN"),
        (vec!["--depth", "0"], "--depth 0"),
        (vec!["--domain-id", "300"], "--domain-id 300"),
        (vec!["--vo-mass", "0"], "--vo-mass 0"),
        (vec!["--namespace", "no//slash"], "node name"),
        (vec!["--node-name", "bad-name"], "node name"),
        (vec!["--server", "127.0.0.1#notaport"], "connect to"),
    ] {
        let (code, err) = run_node(&args);
        assert_eq!(code, 1, "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    // clap's own refusals: exit 2.
    let (code, err) = run_node(&["--rate", "fast"]);
    assert_eq!(code, 2, "{err}");
    let (code, err) = run_node(&["--command-type", "torque"]);
    assert_eq!(code, 2, "{err}");
}

#[test]
fn no_controller_is_a_clear_error() {
    // A bound socket that never answers.
    let silent = std::net::UdpSocket::bind("127.0.0.1:0").expect("bind");
    let port = silent.local_addr().expect("addr").port();
    let (code, err) = run_node(&["--server", &format!("127.0.0.1#{port}")]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("connect to") && err.contains("timeout"),
        "{err}"
    );
}

fn reliable() -> QosProfile {
    QosProfile::publisher_default()
        .reliability(Reliability::Reliable {
            when_full: WhenFull::DEFAULT,
        })
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 })
}

#[test]
fn power_service_status_and_command_type_parameter() {
    let mut fake = FakePeer::start(FakePeerConfig {
        answer_every_period: true,
        center: [0.45, 0.05, 0.25],
        ..Default::default()
    })
    .expect("fake controller");
    let mut child = Command::new(NODE)
        .args([
            "--server",
            &fake.address(),
            "--domain-id",
            &DOMAIN.to_string(),
            "--dds-address",
            "127.0.0.1",
            "--namespace",
            "/arm_test",
            "--duration",
            "25",
        ])
        .env_remove("ROS_DOMAIN_ID")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("node starts");

    let dp = DomainParticipantBuilder::new(DOMAIN)
        .with_only_networks([std::net::IpAddr::from([127, 0, 0, 1])])
        .build()
        .expect("participant");
    let ctx = Context::from_domain_participant(dp).expect("context");
    let mut node = ctx
        .new_node(
            NodeName::new("/arm_test", "power_client").expect("name"),
            NodeOptions::new().enable_rosout(false),
        )
        .expect("node");
    let client = node
        .create_client::<SetBoolRequest, SetBoolResponse>(
            ServiceMapping::Enhanced,
            &Name::new("/arm_test", "set_power").expect("name"),
            &msgs::set_bool_type(),
            // ROS 2's default service QoS: reliable, volatile.
            QosProfile::publisher_default().history(History::KeepLast { depth: 10 }),
            QosProfile::publisher_default().history(History::KeepLast { depth: 10 }),
        )
        .expect("client");
    let params = node
        .create_client::<SetParametersRequest, SetParametersResponse>(
            ServiceMapping::Enhanced,
            &Name::new("/arm_test/hapticctrl", "set_parameters").expect("name"),
            &ServiceTypeName::new("rcl_interfaces", "SetParameters"),
            // ros2-client's parameter services: reliable, volatile.
            QosProfile::publisher_default(),
            QosProfile::publisher_default(),
        )
        .expect("parameter client");
    let status_topic = node
        .create_topic(
            &Name::new("/arm_test", "status").expect("name"),
            msgs::type_name(MsgType::DiagnosticStatus),
            &reliable(),
        )
        .expect("topic");
    let status = node
        .create_subscription::<DiagnosticStatus>(&status_topic, None)
        .expect("subscription");

    let power_value = |d: &DiagnosticStatus| {
        d.values
            .iter()
            .find(|kv| kv.key == "power_on")
            .map(|kv| kv.value.clone())
    };
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut response = None;
    let mut unpowered_seen = false;
    let mut powered_seen = false;
    let mut next_request = Instant::now();
    while Instant::now() < deadline && !(response.is_some() && powered_seen) {
        while let Ok(Some((s, _))) = status.take() {
            match power_value(&s).as_deref() {
                Some("false") if response.is_none() => unpowered_seen = true,
                Some("true") if response.is_some() => powered_seen = true,
                _ => {}
            }
        }
        // Until the service is discovered, requests are lost: ask again.
        if response.is_none() && Instant::now() >= next_request {
            let _ = client.send_request(SetBoolRequest { data: true });
            next_request = Instant::now() + Duration::from_millis(500);
        }
        if let Ok(Some((_, r))) = client.receive_response() {
            response = Some(r);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    // The command type: an unknown one refused, virtmech applied.
    let set_command = |value: &str| {
        let deadline = Instant::now() + Duration::from_secs(10);
        let mut next_request = Instant::now();
        // Responses to the earlier calls' repeated requests are skipped.
        let mut ids = Vec::new();
        while Instant::now() < deadline {
            if Instant::now() >= next_request {
                let id = params.send_request(SetParametersRequest {
                    parameter: vec![Parameter {
                        name: "command_type".into(),
                        value: ParameterValue::String(value.into()),
                    }
                    .into()],
                });
                if let Ok(id) = id {
                    ids.push(id);
                }
                next_request = Instant::now() + Duration::from_millis(500);
            }
            while let Ok(Some((id, r))) = params.receive_response() {
                if ids.contains(&id) {
                    return r.results.into_iter().next();
                }
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        None
    };
    let refused = set_command("torque").expect("a response to command_type torque");
    assert!(!refused.successful, "{refused:?}");
    assert!(refused.reason.contains("torque"), "{refused:?}");
    assert_eq!(fake.stats().command_type, Some(1), "impedance at start");
    let applied = set_command("virtmech").expect("a response to command_type virtmech");
    assert!(applied.successful, "{applied:?}");
    let deadline = Instant::now() + Duration::from_secs(5);
    while fake.stats().command_type != Some(2) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    let st = fake.stats();
    // The controller goes silent: the status turns STALE.
    fake.stop();
    let deadline = Instant::now() + Duration::from_secs(8);
    let mut stale = None;
    while stale.is_none() && Instant::now() < deadline {
        while let Ok(Some((s, _))) = status.take() {
            if s.level == DiagnosticStatus::STALE {
                stale = Some(s);
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = child.kill();
    let _ = child.wait();
    let stale = stale.expect("a STALE status after the controller stopped");
    assert!(stale.message.contains("no answer"), "{stale:?}");
    assert_eq!(st.command_type, Some(2), "the controller got virtmech");
    assert!(st.attached, "and the virtual object");
    let r = response.expect("a response from set_power");
    assert!(r.success, "{r:?}");
    assert_eq!(r.message, "power on");
    assert!(fake.stats().powered, "the controller was powered");
    assert!(unpowered_seen, "status reported the arm unpowered first");
    assert!(
        powered_seen,
        "status reported power on after the service call"
    );
}

/// At a set rate the node republishes the newest answer, but not once the
/// controller has gone silent: the status turns STALE there too.
#[test]
fn set_rate_goes_stale_when_the_controller_stops() {
    let mut fake = FakePeer::start(FakePeerConfig {
        answer_every_period: true,
        center: [0.45, 0.05, 0.25],
        ..Default::default()
    })
    .expect("fake controller");
    let mut child = Command::new(NODE)
        .args([
            "--server",
            &fake.address(),
            "--domain-id",
            &DOMAIN.to_string(),
            "--dds-address",
            "127.0.0.1",
            "--namespace",
            "/arm_rate",
            "--rate",
            "200",
            "--duration",
            "25",
        ])
        .env_remove("ROS_DOMAIN_ID")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("node starts");
    let dp = DomainParticipantBuilder::new(DOMAIN)
        .with_only_networks([std::net::IpAddr::from([127, 0, 0, 1])])
        .build()
        .expect("participant");
    let ctx = Context::from_domain_participant(dp).expect("context");
    let mut node = ctx
        .new_node(
            NodeName::new("/arm_rate", "status_reader").expect("name"),
            NodeOptions::new().enable_rosout(false),
        )
        .expect("node");
    let topic = node
        .create_topic(
            &Name::new("/arm_rate", "status").expect("name"),
            msgs::type_name(MsgType::DiagnosticStatus),
            &reliable(),
        )
        .expect("topic");
    let status = node
        .create_subscription::<DiagnosticStatus>(&topic, None)
        .expect("subscription");
    let wait_for = |level_is_stale: bool, secs: u64| {
        let deadline = Instant::now() + Duration::from_secs(secs);
        while Instant::now() < deadline {
            while let Ok(Some((s, _))) = status.take() {
                if (s.level == DiagnosticStatus::STALE) == level_is_stale {
                    return Some(s);
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    };
    let live = wait_for(false, 15);
    fake.stop();
    let stale = wait_for(true, 8);
    let _ = child.kill();
    let _ = child.wait();
    let live = live.expect("a status while the controller answered");
    assert!(live.values.iter().any(|kv| kv.key == "cycle"), "{live:?}");
    let stale = stale.expect("a STALE status after the controller stopped");
    assert!(stale.message.contains("no answer"), "{stale:?}");
}

/// An authenticated controller in one thread: hap-auth's gate (what the
/// bridge runs) in front of hap-core's PROTO_IN, an answer every 1 ms while
/// a session is open; a proven handshake takes the session and the client
/// it replaced is told (`error` 0x102), as the bridge does.
fn auth_peer(psk: hap_auth::Psk) -> (String, std::sync::Arc<std::sync::atomic::AtomicBool>) {
    use hap_auth::{Action, Gate, Kind};
    use hap_core::proto_in::ProtoIn;
    use hap_core::protocol::{encode, Answer, Frame, FrameHeader, MAX_FRAME_LEN};
    use std::sync::atomic::{AtomicBool, Ordering};
    let sock = std::net::UdpSocket::bind("127.0.0.1:0").expect("bind");
    sock.set_read_timeout(Some(Duration::from_millis(1)))
        .expect("timeout");
    let addr = format!("127.0.0.1#{}", sock.local_addr().expect("addr").port());
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    let st = stop.clone();
    std::thread::spawn(move || {
        let mut gate = Gate::with_random_secret(psk).expect("gate");
        let mut kernel = ProtoIn::new();
        let t0 = Instant::now();
        let mut buf = [0u8; 256];
        let mut seq = 0u32;
        let mut client = None;
        let mut next = Instant::now();
        while !st.load(Ordering::SeqCst) {
            let mut out: Vec<Frame> = Vec::new();
            if let Ok((n, src)) = sock.recv_from(&mut buf) {
                if let Ok(i) = gate.inspect(&buf[..n], src, t0.elapsed()) {
                    match gate.commit(&i, t0.elapsed()) {
                        Action::Reply(w, _) | Action::Challenge(w) => {
                            let _ = sock.send_to(w.bytes(), src);
                        }
                        Action::Forward(v1) => {
                            if i.kind == Kind::Proof {
                                if let (Some(e), Some(old)) = (gate.take_replaced(), client) {
                                    let _ = sock.send_to(e.notice.bytes(), old);
                                }
                                client = Some(src);
                            }
                            out.extend(kernel.handle(v1.bytes(), 1, 1000).reply);
                        }
                    }
                }
            }
            let session = kernel.session();
            if session != 0 && Instant::now() >= next {
                next = Instant::now() + Duration::from_millis(1);
                out.push(Frame::Answer(Answer {
                    cycle: seq,
                    ..Answer::default()
                }));
            }
            for f in out {
                seq += 1;
                let h = FrameHeader {
                    control: 0,
                    session,
                    seq,
                    timestamp_us: 0,
                };
                let mut b = [0u8; MAX_FRAME_LEN];
                let n = encode(&h, &f, &mut b);
                if let (Some(w), Some(c)) = (gate.seal_from_kernel(&b[..n]), client) {
                    let _ = sock.send_to(w.bytes(), c);
                }
            }
        }
    });
    (addr, stop)
}

/// Another key holder takes the arm from the node: the node publishes an
/// ERROR status and stops with the error, its VirtuoseAPI code and the
/// reason 0x102 (it does not go on as if it still had the arm).
#[test]
fn the_node_stops_with_the_error_when_its_session_is_replaced() {
    use std::io::BufRead;
    let dir = std::env::temp_dir().join(format!("ros2_replaced_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("dir");
    let psk = hap_auth::Psk::generate().expect("key");
    let key = dir.join("key");
    psk.write_new(&key).expect("key file");
    let (addr, stop) = auth_peer(psk.clone());
    let mut child = Command::new(NODE)
        .args([
            "--server",
            &format!("{addr}?key={}", key.display()),
            "--domain-id",
            &DOMAIN.to_string(),
            "--dds-address",
            "127.0.0.1",
            "--namespace",
            "/arm_replaced",
            "--duration",
            "30",
        ])
        .env_remove("ROS_DOMAIN_ID")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("node starts");
    // Its stderr, line by line; the node announces itself once it runs.
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let stderr = child.stderr.take().expect("stderr");
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            let _ = tx.send(line);
        }
    });
    let mut lines = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(20);
    while Instant::now() < deadline {
        if let Ok(l) = rx.recv_timeout(Duration::from_millis(100)) {
            let up = l.contains("on DDS domain");
            lines.push(l);
            if up {
                break;
            }
        }
    }
    assert!(
        lines.iter().any(|l| l.contains("on DDS domain")),
        "the node did not start: {lines:?}"
    );
    // Another application with the key opens: it takes the arm.
    let other = virtuose_api::VirtContext::open_with(
        &addr,
        virtuose_api::Options {
            key: Some(psk),
            ..Default::default()
        },
    )
    .expect("the second key holder opens");
    let deadline = Instant::now() + Duration::from_secs(15);
    let code = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s.code();
        }
        if Instant::now() >= deadline {
            let _ = child.kill();
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    while let Ok(l) = rx.recv_timeout(Duration::from_millis(200)) {
        lines.push(l);
    }
    drop(other);
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
    let _ = std::fs::remove_dir_all(&dir);
    let err = lines.join("\n");
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("replaced") && err.contains("(0x102)") && err.contains("VirtuoseAPI error 2"),
        "{err}"
    );
}
