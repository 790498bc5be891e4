//! The shared library binds its own calls to its own definitions: an
//! application built with Haption's 3.x header defines `virt*` wrappers of
//! the same names (they call `virtCallDLL`), which must not receive the
//! library's internal calls (scripts/install-virtuose-api.sh links the
//! installed names the same way).
fn main() {
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    if os == "linux" {
        println!("cargo:rustc-cdylib-link-arg=-Wl,-Bsymbolic-functions");
    }
    println!("cargo:rerun-if-changed=build.rs");
}
