//! Build the C example against the static library and run it against the
//! fake controller.

use std::path::PathBuf;
use std::process::Command;

use virtuose_api::fake_peer::{FakePeer, FakePeerConfig};

fn staticlib() -> Option<PathBuf> {
    // target/<profile>/deps/<this test> -> target/<profile>/libvirtuose_api.a
    let exe = std::env::current_exe().ok()?;
    // (or target/<profile>/deps/ when the library was built as another
    // member's dependency and not uplifted).
    let deps = exe.parent()?;
    let dir = deps.parent()?;
    [
        dir.join("libvirtuose_api.a"),
        deps.join("libvirtuose_api.a"),
    ]
    .into_iter()
    .find(|p| p.exists())
}

#[test]
fn c_example_builds_and_couples() {
    if Command::new("cc").arg("--version").output().is_err() {
        println!("SKIPPED: no C compiler (cc) on this machine");
        return;
    }
    let Some(lib) = staticlib() else {
        panic!("libvirtuose_api.a not found next to the test binary");
    };
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let include = root.join("../../include");
    let src = root.join("examples/c/coupling.c");
    let out = std::env::temp_dir().join(format!("virtuose_coupling_{}", std::process::id()));
    let st = Command::new("cc")
        .args([
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-D_POSIX_C_SOURCE=200809L",
            "-O1",
            "-I",
        ])
        .arg(&include)
        .arg(&src)
        .arg(&lib)
        .args(["-lpthread", "-ldl", "-lm", "-o"])
        .arg(&out)
        .status()
        .expect("run cc");
    assert!(st.success(), "cc failed");

    let peer = FakePeer::start(FakePeerConfig::default()).unwrap();
    let o = Command::new(&out)
        .arg(peer.address())
        .arg("1500")
        .output()
        .expect("run example");
    let _ = std::fs::remove_file(&out);
    let stdout = String::from_utf8_lossy(&o.stdout);
    println!("{stdout}{}", String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "example failed: {:?}", o.status);
    assert!(
        stdout.contains("expected error: invalid argument: time step"),
        "{stdout}"
    );
    assert!(stdout.contains("OK"));
    let st = peer.stats();
    assert!(st.frames.get("vpr_stream").copied().unwrap_or(0) >= 1000);
    assert_eq!(st.frames.get("close_session"), Some(&1));
}

/// Compile `src` (C99, warnings as errors) against include/ and the static
/// library; None when there is no C compiler.
fn build_c(src: &str, name: &str) -> Option<PathBuf> {
    if Command::new("cc").arg("--version").output().is_err() {
        println!("SKIPPED: no C compiler (cc) on this machine");
        return None;
    }
    let lib = staticlib().expect("libvirtuose_api.a not found next to the test binary");
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let out = std::env::temp_dir().join(format!("{name}_{}", std::process::id()));
    let st = Command::new("cc")
        .args([
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-D_POSIX_C_SOURCE=200809L",
            "-O1",
            "-I",
        ])
        .arg(root.join("../../include"))
        .arg(root.join(src))
        .arg(&lib)
        .args(["-lpthread", "-ldl", "-lm", "-o"])
        .arg(&out)
        .status()
        .expect("run cc");
    assert!(st.success(), "cc {src} failed");
    Some(out)
}

#[test]
fn periodic_c_example_runs_its_callback_loop() {
    let Some(exe) = build_c("examples/c/periodic.c", "virtuose_periodic") else {
        return;
    };
    // The handle oscillates 2 cm along x: the callback's spring pushes back.
    let peer = FakePeer::start(FakePeerConfig {
        center: [0.5, 0.05, 0.3],
        amplitude: [0.02, 0.0, 0.0],
        freq_hz: 2.0,
        answer_every_period: true,
        twist_every: 4,
        ..Default::default()
    })
    .unwrap();
    let o = Command::new(&exe)
        .arg(peer.address())
        .arg("500")
        .output()
        .expect("run example");
    let _ = std::fs::remove_file(&exe);
    let stdout = String::from_utf8_lossy(&o.stdout);
    println!("{stdout}{}", String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "example failed: {:?}", o.status);
    assert!(stdout.contains("VirtuoseAPI 4.4"), "{stdout}");
    assert!(stdout.contains("6 axes"), "{stdout}");
    assert!(stdout.contains("OK"));
    let st = peer.stats();
    assert!(st.frames.get("vpr_stream").copied().unwrap_or(0) >= 10);
    // Spring forces reached the coupling (saturated at 5 N by the example).
    let k = hap_core::control::Gains::for_period(hap_core::fixed::Fx::from_ratio(1000, 1_000_000))
        .k_lin
        .to_f64();
    assert!(st.max_vo_offset > 0.1 / k, "{} m", st.max_vo_offset);
    assert!(!st.powered);
    assert_eq!(st.frames.get("close_session"), Some(&1));
}

/// Every function VirtuoseAPI.h declares links against the library: a C
/// file taking the address of each one builds (C and C++).
#[test]
fn every_declared_function_links() {
    if Command::new("cc").arg("--version").output().is_err() {
        println!("SKIPPED: no C compiler (cc) on this machine");
        return;
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let include = root.join("../../include");
    let header = std::fs::read_to_string(include.join("VirtuoseAPI.h")).unwrap();
    let names: Vec<&str> = header
        .lines()
        .filter(|l| l.starts_with("extern ") && l.contains("virt"))
        .filter_map(|l| l.split('(').next()?.split_whitespace().last())
        .map(|n| n.trim_start_matches('*'))
        .collect();
    assert_eq!(names.len(), 118, "{names:?}");
    let mut src =
        String::from("#include \"VirtuoseAPI.h\"\n#include <stdio.h>\nint main(void) {\n");
    for n in &names {
        src.push_str(&format!("    printf(\"%p\\n\", (void *)&{n});\n"));
    }
    src.push_str("    return 0;\n}\n");
    let dir = std::env::temp_dir().join(format!("virt_link_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let c = dir.join("all.c");
    std::fs::write(&c, &src).unwrap();
    let lib = staticlib().expect("libvirtuose_api.a");
    for (compiler, lang) in [("cc", "c"), ("c++", "c++")] {
        if Command::new(compiler).arg("--version").output().is_err() {
            continue;
        }
        let exe = dir.join(format!("all_{lang}"));
        let st = Command::new(compiler)
            .args(["-x", lang, "-Wall", "-Werror", "-I"])
            .arg(&include)
            .arg(&c)
            .args(["-x", "none"])
            .arg(&lib)
            .args(["-lpthread", "-ldl", "-lm", "-o"])
            .arg(&exe)
            .status()
            .expect("run compiler");
        assert!(st.success(), "{compiler} failed to build or link");
        let o = Command::new(&exe).output().unwrap();
        assert!(o.status.success());
        assert_eq!(String::from_utf8_lossy(&o.stdout).lines().count(), 118);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
