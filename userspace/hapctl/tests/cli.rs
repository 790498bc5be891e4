//! hapctl's command line: argument errors, device writes against a fake
//! device directory, log capture + analysis, and the launch script with fake
//! insmod/rmmod.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use hap_core::position_log::LogRecord;

fn hapctl(dev: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hapctl"))
        .env("HAPCTL_DEV_DIR", dev)
        .args(args)
        .output()
        .expect("run hapctl")
}

fn tmpdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hapctl_test_{tag}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn wrong_arguments_fail_clearly() {
    let d = tmpdir("args");
    for (args, needle) in [
        (vec![], "Usage"),
        (vec!["frobnicate"], "unrecognized subcommand"),
        (vec!["power"], "required"),
        (vec!["power", "maybe"], "invalid value 'maybe'"),
        (vec!["start", "--period-us", "abc"], "invalid value 'abc'"),
        (vec!["start", "--period-us", "5"], "not in 100..=10000"),
        (vec!["start", "--period-us", "99"], "not in 100..=10000"),
        (vec!["start", "--period-us", "10001"], "not in 100..=10000"),
        (vec!["log", "--cycles", "0"], "invalid value '0'"),
        (vec!["sim", "live", "1", "2"], "6 values"),
        (vec!["sim", "load"], "required"),
    ] {
        let o = hapctl(&d, &args);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(err(&o).contains(needle), "{args:?}: {}", err(&o));
    }
    // Missing device: a clear message, exit 1.
    let o = hapctl(&d, &["power", "on"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        err(&o).contains("hap_power") && err(&o).contains("is the module loaded"),
        "{}",
        err(&o)
    );
    let o = hapctl(&d, &["sim", "load", "/nonexistent.eff"]);
    assert_eq!(o.status.code(), Some(1));
    let o = hapctl(
        &d,
        &["analyze", "/nonexistent.log", "--out", d.to_str().unwrap()],
    );
    assert_eq!(o.status.code(), Some(1));
}

#[test]
fn arm_one_uses_its_own_devices() {
    let d = tmpdir("arm1");
    std::fs::write(d.join("hap_power"), "").unwrap();
    std::fs::write(d.join("hap1_power"), "").unwrap();
    std::fs::write(d.join("hap1_effort"), "").unwrap();
    let o = hapctl(&d, &["--arm", "1", "power", "on"]);
    assert!(o.status.success(), "{}", err(&o));
    assert_eq!(std::fs::read_to_string(d.join("hap1_power")).unwrap(), "1");
    assert_eq!(std::fs::read_to_string(d.join("hap_power")).unwrap(), "");
    let o = hapctl(
        &d,
        &["sim", "live", "1", "0", "0", "0", "0", "0", "--arm", "1"],
    );
    assert!(o.status.success(), "{}", err(&o));
    assert!(std::fs::read_to_string(d.join("hap1_effort"))
        .unwrap()
        .starts_with("live "));
    let o = hapctl(&d, &["--arm", "2", "power", "on"]);
    assert!(!o.status.success());
    assert!(err(&o).contains("--arm"), "{}", err(&o));
}

#[test]
fn power_sim_and_stats_write_and_read_devices() {
    let d = tmpdir("dev");
    std::fs::write(d.join("hap_power"), "").unwrap();
    std::fs::write(d.join("hap_effort"), "").unwrap();
    let o = hapctl(&d, &["power", "on"]);
    assert!(o.status.success(), "{}", err(&o));
    assert_eq!(std::fs::read_to_string(d.join("hap_power")).unwrap(), "1");
    hapctl(&d, &["power", "off"]);
    assert_eq!(std::fs::read_to_string(d.join("hap_power")).unwrap(), "0");

    let good = d.join("good.eff");
    std::fs::write(
        &good,
        "# t fx fy fz tx ty tz deadman\n0 0 0 0 0 0 0 1\n1000 2.5 0 -1 0 0 0 1\n",
    )
    .unwrap();
    let o = hapctl(&d, &["sim", "load", good.to_str().unwrap()]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(std::fs::read_to_string(d.join("hap_effort"))
        .unwrap()
        .contains("2.5"));

    let bad = d.join("bad.eff");
    std::fs::write(&bad, "0 0 0 0 0 0 0\n10 0 zero 0 0 0 0\n").unwrap();
    std::fs::write(d.join("hap_effort"), "").unwrap();
    let o = hapctl(&d, &["sim", "load", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(err(&o).contains("line 2"), "{}", err(&o));
    assert_eq!(
        std::fs::read_to_string(d.join("hap_effort")).unwrap(),
        "",
        "bad file reached the device"
    );

    let o = hapctl(&d, &["sim", "live", "1", "0", "-2", "0", "0", "0"]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(std::fs::read_to_string(d.join("hap_effort"))
        .unwrap()
        .starts_with("live 1.0000 0.0000 -2.0000"));

    std::fs::write(
        d.join("hap_stats"),
        "version: 1\nperiod_us: 1000\ncycles: 5\n",
    )
    .unwrap();
    let ps = d.join("proto.stats");
    std::fs::write(&ps, "received: 3\nforwarded: 2\n").unwrap();
    let o = hapctl(&d, &["stats", "--proto-stats", ps.to_str().unwrap()]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", err(&o));
    assert!(out.contains("cycles") && out.contains("forwarded"), "{out}");
}

fn fake_log(path: &Path, n: u64) {
    let mut bytes = Vec::new();
    for i in 0..n {
        // The ring dropped five records after the first 300.
        if (300..305).contains(&i) {
            continue;
        }
        let mut r = LogRecord::ZERO;
        r.cycle = 100 + i;
        r.time_us = r.cycle * 1000;
        let t = i as f64 * 1e-3;
        r.handle_position =
            hap_core::fixed::Vec3::from_f64([0.05 * (6.0 * t).sin(), 0.01, 0.02 * t]);
        r.coupling_force =
            hap_core::fixed::Vec3::from_f64([3.0 * (6.0 * t).cos().abs(), 0.0, -1.0]);
        let mut b = [0u8; LogRecord::SIZE];
        r.encode(&mut b);
        bytes.extend_from_slice(&b);
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn log_capture_and_analyze() {
    let d = tmpdir("log");
    fake_log(&d.join("hap_simlog"), 500);
    let out = d.join("run.log");
    let o = hapctl(
        &d,
        &["log", "--out", out.to_str().unwrap(), "--cycles", "300"],
    );
    assert!(o.status.success(), "{}", err(&o));
    assert_eq!(
        std::fs::metadata(&out).unwrap().len(),
        300 * LogRecord::SIZE as u64
    );
    // The whole log: the recorder counts the five records the ring dropped
    // and shows the module's own count.
    std::fs::write(d.join("hap_stats"), "version: 1\nsimlog.dropped: 5\n").unwrap();
    let all = d.join("all.log");
    let summ = d.join("log.txt");
    let o = hapctl(
        &d,
        &[
            "log",
            "--out",
            all.to_str().unwrap(),
            "--summary",
            summ.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
    let s = std::fs::read_to_string(&summ).unwrap();
    assert!(s.contains("records: 495\n"), "{s}");
    assert!(s.contains("dropped_records: 5\n"), "{s}");
    assert!(s.contains("module.simlog.dropped: 5\n"), "{s}");
    assert!(err(&o).contains("dropped_records: 5"), "{}", err(&o));
    // CSV on stdout without --out.
    let o = hapctl(&d, &["log", "--cycles", "2"]);
    let csv = String::from_utf8_lossy(&o.stdout);
    assert_eq!(csv.lines().count(), 3, "{csv}");
    assert!(csv.lines().nth(1).unwrap().starts_with("100,"));

    if cfg!(not(feature = "analyze")) {
        println!("SKIPPED: hapctl built without the analyze feature");
        return;
    }
    let stats = d.join("stats.txt");
    std::fs::write(
        &stats,
        "version: 1\nperiod_us: 1000\ncycles: 300\nmisses: 0\nwakeup.count: 300\nwakeup.min_ns: 2000\nwakeup.avg_ns: 5000\nwakeup.max_ns: 40000\nwakeup.p50_us: 4\nwakeup.p99_us: 20\nwakeup.p99_9_us: 35\nexec.count: 300\nexec.min_ns: 10000\nexec.avg_ns: 15000\nexec.max_ns: 90000\nexec.p50_us: 14\nexec.p99_us: 60\nexec.p99_9_us: 80\n",
    )
    .unwrap();
    let plots = d.join("plots");
    let o = hapctl(
        &d,
        &[
            "analyze",
            out.to_str().unwrap(),
            "--out",
            plots.to_str().unwrap(),
            "--stats",
            stats.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
    for f in [
        "trajectory",
        "forces",
        "torques",
        "speed",
        "energy",
        "events",
    ] {
        for ext in ["png", "svg"] {
            let p = plots.join(format!("{f}.{ext}"));
            let len = std::fs::metadata(&p).map(|m| m.len()).unwrap_or(0);
            assert!(len > 1000, "{} missing or empty", p.display());
        }
    }
    let html = std::fs::read_to_string(plots.join("summary.html")).unwrap();
    assert!(html.contains("<img src=\"forces.png\""), "{html}");
    let png = std::fs::read(plots.join("trajectory.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    // Garbage instead of a log: clear error.
    let junk = d.join("junk.log");
    std::fs::write(&junk, b"not a log").unwrap();
    let o = hapctl(
        &d,
        &[
            "analyze",
            junk.to_str().unwrap(),
            "--out",
            plots.to_str().unwrap(),
        ],
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(err(&o).contains("no position-log records"), "{}", err(&o));
}

#[test]
fn launch_script_starts_and_stops_with_fake_tools() {
    let d = tmpdir("script");
    let bin = d.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    let calls = d.join("calls");
    for tool in ["insmod", "rmmod"] {
        let p = bin.join(tool);
        std::fs::write(
            &p,
            format!("#!/bin/sh\necho \"{tool} $*\" >> {}\n", calls.display()),
        )
        .unwrap();
        Command::new("chmod").arg("+x").arg(&p).status().unwrap();
    }
    // The bridge: records its arguments, then lives on.
    let proto = bin.join("fake_proto");
    std::fs::write(
        &proto,
        format!(
            "#!/bin/sh\necho \"proto $*\" >> {}\nexec sleep 30\n",
            calls.display()
        ),
    )
    .unwrap();
    Command::new("chmod")
        .arg("+x")
        .arg(&proto)
        .status()
        .unwrap();
    let key = d.join("hap.key");
    let ko = d.join("hapticctrl.ko");
    std::fs::write(&ko, "").unwrap();
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scripts/hapticctrl.sh");
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let run_env = |args: &[&str], env: &[(&str, &str)]| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_hapctl"));
        c.args(args)
            .arg("--script")
            .arg(&script)
            .env("PATH", &path)
            .env("HAP_MODULE", &ko)
            .env("HAP_PROTO", &proto)
            .env("HAP_PROTO_ARGS", "--port 5001")
            .env("HAP_KEY", &key)
            .env("HAP_USER", "")
            .env("HAP_RUN", &d)
            .env_remove("HAP_INSECURE");
        for (k, v) in env {
            c.env(k, v);
        }
        c.output().unwrap()
    };
    let run = |args: &[&str]| run_env(args, &[]);
    // No key and no HAP_INSECURE: refused, nothing started.
    let o = run(&["start"]);
    assert!(!o.status.success());
    assert!(err(&o).contains("hapctl keygen"), "{}", err(&o));
    assert!(!calls.exists());
    // Unauthenticated only on request, and loudly.
    let o = run_env(&["start"], &[("HAP_INSECURE", "1")]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(err(&o).contains("UNAUTHENTICATED"), "{}", err(&o));
    let c = std::fs::read_to_string(&calls).unwrap();
    assert!(c.contains("proto --insecure --port 5001"), "{c}");
    assert!(run(&["stop"]).status.success());
    std::fs::remove_file(&calls).unwrap();
    // With a key: the bridge gets it.
    assert!(hapctl(&d, &["keygen", key.to_str().unwrap()])
        .status
        .success());
    let o = run(&["start", "--period-us", "2000"]);
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        err(&o)
    );
    let c = std::fs::read_to_string(&calls).unwrap();
    assert!(
        c.contains(&format!("insmod {} period_us=2000", ko.display())),
        "{c}"
    );
    assert!(
        c.contains(&format!("proto --key {} --port 5001", key.display())),
        "{c}"
    );
    let pid: i32 = std::fs::read_to_string(d.join("proto_interface.pid"))
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    assert!(Path::new(&format!("/proc/{pid}")).exists());
    // A second start is refused (bridge already running).
    let o = run(&["start"]);
    assert!(!o.status.success());
    let o = run(&["stop"]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("proto_interface stopped"));
    // Two arms: the module gets arms=2 and arm 1 a bridge of its own (its
    // port, devices and counters); stop ends both.
    std::fs::remove_file(&calls).unwrap();
    let o = run(&["start", "--arms", "2"]);
    assert!(o.status.success(), "{}", err(&o));
    let c = std::fs::read_to_string(&calls).unwrap();
    assert!(
        c.contains(&format!("insmod {} arms=2", ko.display())),
        "{c}"
    );
    assert!(
        c.contains(&format!("proto --key {} --port 5001", key.display())),
        "{c}"
    );
    assert!(
        c.contains(&format!(
            "proto --key {} --stats-file {}/proto_interface1.stats --rtf-in /dev/hap1_rtf_in --rtf-out /dev/hap1_rtf_out --port 5001",
            key.display(),
            d.display()
        )),
        "{c}"
    );
    assert!(d.join("proto_interface1.pid").exists());
    let o = run(&["stop"]);
    assert!(o.status.success(), "{}", err(&o));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert_eq!(out.matches("proto_interface stopped").count(), 2, "{out}");
    assert!(!d.join("proto_interface1.pid").exists());
    let o = run(&["start", "--arms", "3"]);
    assert!(!o.status.success());
    // As root, with a user for the bridge: its own stats directory, and the
    // two FIFO devices (here plain files) given to its group, mode 0660.
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    if std::fs::metadata("/proc/self").map(|m| m.uid()).ok() == Some(0) {
        let dev = d.join("dev");
        std::fs::create_dir_all(&dev).unwrap();
        for n in ["hap_rtf_in", "hap_rtf_out", "hap_power"] {
            std::fs::write(dev.join(n), "").unwrap();
            std::fs::set_permissions(dev.join(n), std::fs::Permissions::from_mode(0o600)).unwrap();
        }
        let o = run_env(
            &["start"],
            &[
                ("HAP_USER", "nobody:nogroup"),
                ("HAP_DEV", dev.to_str().unwrap()),
            ],
        );
        assert!(o.status.success(), "{}", err(&o));
        let c = std::fs::read_to_string(&calls).unwrap();
        assert!(
            c.contains(&format!(
                "--user nobody:nogroup --stats-file {}/hapticctrl/proto_interface.stats",
                d.display()
            )),
            "{c}"
        );
        for n in ["hap_rtf_in", "hap_rtf_out"] {
            let m = std::fs::metadata(dev.join(n)).unwrap();
            assert_eq!((m.gid(), m.mode() & 0o777), (65534, 0o660), "{n}");
        }
        let m = std::fs::metadata(dev.join("hap_power")).unwrap();
        assert_eq!((m.gid(), m.mode() & 0o777), (0, 0o600), "only the FIFOs");
        assert_eq!(
            std::fs::metadata(d.join("hapticctrl")).unwrap().uid(),
            65534
        );
        assert!(run_env(&["stop"], &[("HAP_DEV", dev.to_str().unwrap())])
            .status
            .success());
    }
    assert!(!d.join("proto_interface.pid").exists());
    std::thread::sleep(std::time::Duration::from_millis(100));
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    assert!(
        stat.is_empty() || stat.contains(") Z"),
        "bridge still alive: {stat}"
    );
}

#[test]
fn keygen_writes_a_private_key_once() {
    use std::os::unix::fs::PermissionsExt;
    let d = tmpdir("keygen");
    let key = d.join("hap.key");
    let o = hapctl(&d, &["keygen", key.to_str().unwrap()]);
    assert!(o.status.success(), "{}", err(&o));
    let mode = std::fs::metadata(&key).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o600);
    let k1 = hap_auth::Psk::load(&key).unwrap();
    // Never overwritten.
    let o = hapctl(&d, &["keygen", key.to_str().unwrap()]);
    assert!(!o.status.success());
    assert_eq!(hap_auth::Psk::load(&key).unwrap(), k1);
    // Two keys differ.
    let key2 = d.join("hap2.key");
    assert!(hapctl(&d, &["keygen", key2.to_str().unwrap()])
        .status
        .success());
    assert_ne!(hap_auth::Psk::load(&key2).unwrap(), k1);
    let _ = std::fs::remove_dir_all(&d);
}
