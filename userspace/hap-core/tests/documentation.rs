//! The documents are references: a figure they quote that the code
//! determines (a structure's size, a word count, a constant, the committed
//! fuzz corpus) is checked here against the code, and every table stays
//! readable (no cell over 300 characters). The model checks' interleaving
//! counts are checked where they are computed (`spsc::tests`,
//! `seqlock::tests`: each run's count must appear in architecture.md).

use std::path::{Path, PathBuf};

use hap_core::arm;
use hap_core::effort::EFFORT_RECORD_BYTES;
use hap_core::position_log::LogRecord;
use hap_core::stats::{HapStats, WordSet, STATS_WORDS};
use hap_core::vp::VPR_LATCH_WORDS;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(root().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// The number written right after the first `marker` of `text` (digits,
/// with spaces between groups of three, and an optional decimal part),
/// as written.
fn number_after(text: &str, marker: &str, doc: &str) -> String {
    let at = text.find(marker).unwrap_or_else(|| {
        panic!("{doc}: no `{marker}` (the figure's wording changed: update this test)")
    });
    let rest = &text[at + marker.len()..];
    let start = rest
        .find(|c: char| c.is_ascii_digit())
        .unwrap_or_else(|| panic!("{doc}: no number after `{marker}`"));
    let chars: Vec<char> = rest[start..].chars().collect();
    let mut out = String::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_ascii_digit() || c == '.' && chars.get(i + 1).is_some_and(|d| d.is_ascii_digit()) {
            out.push(c);
        } else if c == ' '
            && chars.len() > i + 3
            && chars[i + 1..i + 4].iter().all(|d| d.is_ascii_digit())
            && !chars.get(i + 4).is_some_and(|d| d.is_ascii_digit())
            && !out.contains('.')
        {
            // a thousands separator: "24 384"
        } else {
            break;
        }
        i += 1;
    }
    out
}

fn integer_after(text: &str, marker: &str, doc: &str) -> usize {
    let n = number_after(text, marker, doc);
    n.parse()
        .unwrap_or_else(|_| panic!("{doc}: `{marker}` is followed by {n:?}, not an integer"))
}

#[test]
fn the_statistics_record_and_its_publication() {
    let timing = read("Documentation/timing.md");
    let size = std::mem::size_of::<HapStats>();
    assert_eq!(
        integer_after(&timing, "`HapStats` (", "timing.md"),
        size,
        "timing.md: HapStats is {size} bytes"
    );
    let arch = read("Documentation/architecture.md");
    let kib = integer_after(&arch, "(`HapStats`, ~", "architecture.md");
    assert_eq!(
        kib,
        (size + 512) / 1024,
        "architecture.md: HapStats is {size} bytes"
    );
    assert_eq!(
        integer_after(&arch, "reader copies the ", "architecture.md"),
        STATS_WORDS,
        "architecture.md: the published statistics are STATS_WORDS words"
    );
    // A record in use: two cycles, so that each series has a last bucket.
    let mut st = Box::new(HapStats::new(1000));
    st.record_cycle(1_000_000, 1_000_200, 1_003_000, 1_070_000, true);
    st.record_cycle(2_000_000, 2_000_300, 2_003_000, 2_070_000, true);
    let mut recent = 0;
    st.visit_words(WordSet::Recent, |_, _| recent += 1);
    assert_eq!(
        integer_after(&arch, "(`WordSet::Recent`, ", "architecture.md"),
        recent,
        "architecture.md: WordSet::Recent visits {recent} words"
    );
}

#[test]
fn the_records_the_devices_carry() {
    let arch = read("Documentation/architecture.md");
    assert_eq!(
        integer_after(&arch, "the VPr latch: `SeqWords` over ", "architecture.md"),
        VPR_LATCH_WORDS
    );
    assert_eq!(
        integer_after(&arch, "the latest `VpReceived` as\n", "architecture.md"),
        VPR_LATCH_WORDS
    );
    assert_eq!(
        integer_after(&arch, "(2 records of up to ", "architecture.md"),
        EFFORT_RECORD_BYTES
    );
    assert_eq!(
        integer_after(&arch, "pushes one record (at most ", "architecture.md"),
        EFFORT_RECORD_BYTES
    );
    // Every "N-byte" log record any document names.
    let sim = read("Documentation/simulator.md");
    assert_eq!(
        integer_after(&sim, "`LogRecord` version 2, ", "simulator.md"),
        LogRecord::SIZE
    );
    for doc in ["Documentation/architecture.md", "Documentation/timing.md"] {
        let text = read(doc);
        let mut seen = 0;
        for (at, _) in text.match_indices("-byte") {
            let before: String = text[..at]
                .chars()
                .rev()
                .take_while(|c| c.is_ascii_digit())
                .collect::<Vec<_>>()
                .into_iter()
                .rev()
                .collect();
            let after = &text[at + 5..];
            if !before.is_empty()
                && (after.starts_with(" records") || after.starts_with(" `LogRecord`"))
            {
                seen += 1;
                assert_eq!(before.parse::<usize>().unwrap(), LogRecord::SIZE, "{doc}");
            }
        }
        assert!(seen > 0, "{doc}: no log record size quoted");
    }
}

#[test]
fn the_committed_fuzz_corpus() {
    let dir = root().join("userspace/hap-core/fuzz/corpus");
    let mut n = 0;
    for target in std::fs::read_dir(&dir).unwrap() {
        let target = target.unwrap().path();
        if target.is_dir() {
            n += std::fs::read_dir(&target)
                .unwrap()
                .filter(|e| e.as_ref().unwrap().path().is_file())
                .count();
        }
    }
    let rel = read("Documentation/reliability.md");
    assert_eq!(
        integer_after(&rel, "minimised corpus committed (", "reliability.md"),
        n,
        "reliability.md: the committed corpus holds {n} inputs"
    );
}

#[test]
fn the_arm_model_link_lengths() {
    // As the controller computes with them (16 fractional bits), quoted to
    // 7 decimals.
    let sim = read("Documentation/simulator.md");
    for (marker, value) in [
        ("H0 = ", arm::H0),
        ("L1 = ", arm::L1),
        ("L2 = ", arm::L2),
        ("L3 = ", arm::L3),
    ] {
        let quoted = number_after(&sim, marker, "simulator.md");
        assert_eq!(
            quoted,
            format!("{:.7}", value.to_f64()),
            "simulator.md: {marker}"
        );
    }
}

/// The cells of a Markdown table row (a `|` inside backticks or escaped
/// does not split).
fn cells(line: &str) -> Vec<String> {
    let mut out = vec![String::new()];
    let mut code = false;
    let mut prev = ' ';
    for c in line.trim().chars() {
        if c == '`' {
            code = !code;
        }
        if c == '|' && !code && prev != '\\' {
            out.push(String::new());
        } else {
            out.last_mut().unwrap().push(c);
        }
        prev = c;
    }
    out
}

fn documents() -> Vec<PathBuf> {
    let mut v = vec![root().join("README.md")];
    for d in ["Documentation"] {
        for e in std::fs::read_dir(root().join(d)).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "md") {
                v.push(p);
            }
        }
    }
    for e in std::fs::read_dir(root().join("userspace")).unwrap() {
        let p = e.unwrap().path().join("README.md");
        if p.exists() {
            v.push(p);
        }
    }
    v
}

#[test]
fn no_table_cell_is_over_300_characters() {
    let mut long = Vec::new();
    let docs = documents();
    assert!(docs.len() >= 10, "{docs:?}");
    for p in docs {
        let text = std::fs::read_to_string(&p).unwrap();
        for (i, line) in text.lines().enumerate() {
            if !line.trim_start().starts_with('|') {
                continue;
            }
            for c in cells(line) {
                let n = c.trim().chars().count();
                if n > 300 {
                    long.push(format!(
                        "{}:{}: {n} characters: {}…",
                        p.strip_prefix(root()).unwrap_or(&p).display(),
                        i + 1,
                        c.trim().chars().take(60).collect::<String>()
                    ));
                }
            }
        }
    }
    assert!(
        long.is_empty(),
        "table cells over 300 characters:\n{}",
        long.join("\n")
    );
}

#[test]
fn the_number_reader_reads_what_the_documents_write() {
    assert_eq!(number_after("is `X` (24 384 B)", "`X` (", "t"), "24384");
    assert_eq!(number_after("L3 = 0.0799866 m", "L3 = ", "t"), "0.0799866");
    assert_eq!(number_after("over 20 words", "over ", "t"), "20");
    assert_eq!(number_after("1 305 / 34 208", "", "t"), "1305");
    assert_eq!(cells("| a `x|y` | b \\| c |").len(), 4);
}
