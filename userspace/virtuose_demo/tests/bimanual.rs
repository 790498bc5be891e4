//! The demo's bimanual scene (`--server2`) against two fake controllers,
//! one per arm, over UDP: each fake's handle squeezes in and rises, then
//! parts and sinks; the two hands coupled to them grip the object between
//! them and lift it off the floor, then drop it.

use std::process::Command;

#[test]
fn two_arms_hold_the_object_between_them() {
    let dir = std::env::temp_dir().join(format!("hap-bimanual-{}", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_virtuose_demo"))
        .args(["--server", "fake", "--server2", "fake", "--headless"])
        .args(["--duration", "5", "--results"])
        .arg(&dir)
        .output()
        .expect("run virtuose_demo");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary = std::fs::read_to_string(dir.join("summary.txt")).expect("summary.txt");
    let _ = std::fs::remove_dir_all(&dir);
    let v = |k: &str| -> f64 {
        summary
            .lines()
            .find_map(|l| l.strip_prefix(&format!("{k}: ")))
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no {k} in\n{summary}"))
    };
    assert_eq!(v("controller_silent"), 0.0);
    let cycles = v("cycles");
    assert!(cycles > 1000.0, "{summary}");
    for arm in ["arm0", "arm1"] {
        assert!(
            v(&format!("{arm}_answers")) > cycles / 2.0,
            "{arm}: {summary}"
        );
    }
    // Held (both hands on it, off the floor) a good part of each squeeze,
    // lifted by more than 5 mm.
    assert!(v("held_cycles") > 500.0, "{summary}");
    assert!(v("object_max_lift_m") > 0.005, "{summary}");
    // And not held the whole time: the hands part and it drops.
    assert!(v("held_cycles") < cycles * 0.8, "{summary}");
}
