//! hap-core is compiled into the kernel module by source path
//! (`#[path = ".../hap-core/src/lib.rs"] mod hap_core;` in module/hapticctrl.rs).
//! There `crate::` names the module's crate root, not hap-core, so hap-core's
//! files must name each other with `super::` (each is a direct child of lib.rs).
//! Float and i128 code must stay behind `cfg(test)` / `feature = "float"`.

use std::fs;

fn sources() -> Vec<(String, String)> {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/src");
    let mut out = Vec::new();
    for entry in fs::read_dir(dir).expect("read src/") {
        let path = entry.expect("dir entry").path();
        if path.extension().is_some_and(|e| e == "rs") {
            let text = fs::read_to_string(&path).expect("read source");
            out.push((path.display().to_string(), text));
        }
    }
    assert!(out.len() >= 4, "hap-core sources not found");
    out
}

#[test]
fn no_crate_paths_in_hap_core() {
    let mut offenders = Vec::new();
    for (path, text) in sources() {
        for (i, line) in text.lines().enumerate() {
            if line.contains("crate::") && !line.trim_start().starts_with("//") {
                offenders.push(format!("{path}:{}: {}", i + 1, line.trim()));
            }
        }
    }
    assert!(
        offenders.is_empty(),
        "use `super::` instead of `crate::` in hap-core (it is included by #[path] into the kernel module):\n{}",
        offenders.join("\n")
    );
}

#[test]
fn no_i128_in_hap_core_kernel_code() {
    // A crude but effective guard: i128/u128 may only appear after a
    // `#[cfg(test)]` test module starts in a file.
    let mut offenders = Vec::new();
    for (path, text) in sources() {
        let kernel_part = text.split("#[cfg(test)]").next().unwrap_or("");
        for (i, line) in kernel_part.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            if code.contains("i128") || code.contains("u128") {
                offenders.push(format!("{path}:{}: {}", i + 1, line.trim()));
            }
        }
    }
    assert!(
        offenders.is_empty(),
        "128-bit integers in kernel-compiled code:\n{}",
        offenders.join("\n")
    );
}
