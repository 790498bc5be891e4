//! Documentation/userguide.md's table of Haption's functions is exact: one
//! row per function `include/VirtuoseAPI.h` declares, and the functions it
//! marks "not implemented" are exactly those the library answers with
//! `VIRT_E_NOT_IMPLEMENTED` whatever the arguments (the `not_implemented!`
//! list of `src/ffi.rs`).

use std::collections::BTreeSet;
use std::path::PathBuf;

fn read(rel: &str) -> String {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    std::fs::read_to_string(root.join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

#[test]
fn the_userguide_table_lists_every_function_with_its_status() {
    let header = read("../../include/VirtuoseAPI.h");
    let declared: BTreeSet<String> = header
        .lines()
        .filter(|l| l.starts_with("extern ") && l.contains("virt"))
        .filter_map(|l| l.split('(').next()?.split_whitespace().last())
        .map(|n| n.trim_start_matches('*').to_string())
        .collect();
    assert_eq!(declared.len(), 118, "{declared:?}");

    let guide = read("../../Documentation/userguide.md");
    let section = guide
        .split("\n## ")
        .find(|s| s.starts_with("virtuose_api (C): Haption's VirtuoseAPI"))
        .expect("the VirtuoseAPI section of the userguide");
    let mut rows = Vec::new();
    for l in section.lines() {
        let cells: Vec<&str> = l.split('|').map(str::trim).collect();
        if cells.len() >= 4 && cells[1].starts_with("`virt") && cells[1].ends_with('`') {
            rows.push((cells[1].trim_matches('`').to_string(), cells[2].to_string()));
        }
    }
    let listed: BTreeSet<String> = rows.iter().map(|(n, _)| n.clone()).collect();
    assert_eq!(rows.len(), listed.len(), "a function listed twice");
    assert_eq!(listed, declared, "table rows vs VirtuoseAPI.h");
    for (n, s) in &rows {
        assert!(s == "yes" || s == "not implemented", "{n}: status '{s}'");
    }
    let documented_ni: BTreeSet<String> = rows
        .iter()
        .filter(|(_, s)| s == "not implemented")
        .map(|(n, _)| n.clone())
        .collect();

    let src = read("src/ffi.rs");
    let start = src
        .find("\nnot_implemented! {")
        .expect("the not_implemented! list");
    let end = start + src[start..].find("\n}").expect("end of the list");
    let library_ni: BTreeSet<String> = src[start..end]
        .lines()
        .skip(2)
        .filter_map(|l| l.trim().split('(').next())
        .filter(|n| n.starts_with("virt"))
        .map(str::to_string)
        .collect();
    assert_eq!(documented_ni, library_ni, "userguide vs src/ffi.rs");
}
