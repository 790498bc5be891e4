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
