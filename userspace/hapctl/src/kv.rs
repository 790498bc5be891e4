//! `key: value` text (the shape of /dev/hap_stats and proto_interface's
//! counters file) and its pretty table.

/// Parse `key: value` lines; blank and malformed lines are skipped.
pub fn parse(text: &str) -> Vec<(String, String)> {
    hap_core::stats::key_values(text)
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

/// Aligned two-column table.
pub fn table(kv: &[(String, String)]) -> String {
    let w = kv.iter().map(|(k, _)| k.len()).max().unwrap_or(0);
    let mut s = String::new();
    for (k, v) in kv {
        s.push_str(&format!("  {k:<w$}  {v}\n"));
    }
    s
}

#[cfg(test)]
mod tests {
    #[test]
    fn parse_and_table() {
        let kv = super::parse("a: 1\n\nnonsense\nlong_key: x y\n: z\n");
        assert_eq!(kv.len(), 2);
        assert_eq!(super::table(&kv), "  a         1\n  long_key  x y\n");
    }
}
