//! Property tests for clock.rs (supervisor vs a reference model) and
//! stats.rs (percentiles vs a sorted vector, render → parse round trip).

use hap_core::clock::*;
use hap_core::mode::Mode;
use hap_core::protocol::DecodeError;
use hap_core::stats::*;
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]

    /// Fail-safe exactly at the first 5th consecutive miss; never before;
    /// mode follows the documented rules.
    #[test]
    fn supervisor_matches_model(working in proptest::collection::vec(prop::bool::weighted(0.3), 1..400)) {
        let mut s = Supervisor::new();
        let (mut run, mut good, mut degraded, mut failed) = (0u32, 0u32, false, false);
        for w in working {
            let v = s.check(w);
            if failed {
                prop_assert_eq!(v, Verdict::FailSafe(FailSafeCause::MissLimit));
                continue;
            }
            if w {
                run += 1;
                good = 0;
                degraded = true;
                if run == MISS_LIMIT {
                    failed = true;
                    prop_assert_eq!(v, Verdict::FailSafe(FailSafeCause::MissLimit));
                } else {
                    prop_assert_eq!(v, Verdict::Miss { consecutive: run });
                }
            } else {
                run = 0;
                if degraded {
                    good += 1;
                    if good == DEGRADED_EXIT_GOOD_CYCLES {
                        degraded = false;
                        good = 0;
                    }
                }
                let mode = if degraded { Mode::Degraded } else { Mode::Main };
                prop_assert_eq!(v, Verdict::Good { mode });
            }
        }
    }

    #[test]
    fn quantiles_match_sorted_reference(values in proptest::collection::vec(0u64..1_500_000, 1..3000), num in 0u64..=1000) {
        let mut t = TimingStat::new();
        for &v in &values { t.record_ns(v); }
        let mut us: Vec<u64> = values.iter().map(|v| (v / 1000).min(HIST_BUCKETS as u64)).collect();
        us.sort_unstable();
        let n = us.len() as u64;
        for (q, d) in [(num, 1000u64), (P50, 1_000_000), (P99, 1_000_000), (P999, 1_000_000)] {
            let rank = (n * q).div_ceil(d).max(1);
            prop_assert_eq!(u64::from(t.histogram().quantile_us(q, d)), us[(rank - 1) as usize]);
        }
        prop_assert_eq!(t.min_ns(), *values.iter().min().unwrap());
        prop_assert_eq!(t.max_ns(), *values.iter().max().unwrap());
        prop_assert_eq!(t.avg_ns(), values.iter().sum::<u64>() / n);
    }

    #[test]
    fn render_parse_round_trip(
        lat in proptest::collection::vec(0u64..2_000_000, 0..200),
        tops in proptest::collection::vec(900_000u64..1_100_000, 0..200),
        rejects in proptest::collection::vec(0usize..DecodeError::COUNT, 0..50),
        counters in any::<[u64; 4]>(),
        period in PERIOD_MIN_US..=PERIOD_MAX_US,
    ) {
        let mut s = HapStats::new(period);
        for &l in &lat { s.wakeup.record_ns(l); s.exec.record_ns(l / 3); }
        let mut now = 0u64;
        for &d in &tops { now += d; s.jitter.top(now); }
        for &r in &rejects { s.record_reject(DecodeError::from_index(r).unwrap()); }
        s.counters.frames_in = counters[0];
        s.counters.frames_out = counters[1];
        s.counters.answers_dropped = counters[2];
        s.counters.cycles = counters[3];
        let mut buf = [0u8; RENDER_MAX];
        let r = s.render(&mut buf);
        prop_assert!(!r.truncated);
        let text = std::str::from_utf8(&buf[..r.len]).unwrap();
        prop_assert_eq!(parse_summary(text), Ok(s.summary()));
    }
}

#[test]
fn supervisor_and_stats_agree() {
    let mut sup = Supervisor::new();
    let mut st = HapStats::new(DEFAULT_PERIOD_US);
    let pattern = [
        false, true, true, false, true, true, true, true, false, false, true,
    ];
    for w in pattern.iter().cycle().take(500) {
        let v = sup.check(*w);
        st.record_verdict(&v);
    }
    assert_eq!(st.counters.misses, sup.total_misses());
    assert_eq!(
        st.counters.max_consecutive_misses,
        u64::from(sup.max_consecutive_misses())
    );
    assert_eq!(st.counters.cycles, sup.checks());
    assert_eq!(st.counters.fail_safe, 0);
    for _ in 0..5 {
        st.record_verdict(&sup.check(true));
    }
    assert_eq!(sup.fail_safe_cause(), Some(FailSafeCause::MissLimit));
    assert_eq!(st.counters.fail_safe, 1);
    assert_eq!(st.counters.misses, sup.total_misses());
    assert_eq!(st.counters.max_consecutive_misses, 5);
}

#[test]
fn record_cycle_counts_only_what_servo_did() {
    use hap_core::stats::HapStats;
    let mut st = HapStats::new(1000);
    // Woke 3 us after expiry, ran 60 us.
    st.record_cycle(1_000_000, 1_000_500, 1_003_000, 1_063_000, true);
    // Still working at the check: wake-up counted, execution not.
    st.record_cycle(2_000_000, 2_000_400, 2_004_000, 1_063_000, false);
    // Did not start this cycle (start is the previous one's): nothing.
    st.record_cycle(3_000_000, 3_000_300, 2_004_000, 2_900_000, false);
    assert_eq!(st.wakeup.count(), 2);
    assert_eq!(st.wakeup.max_ns(), 4_000);
    assert_eq!(st.exec.count(), 1);
    assert_eq!(st.exec.max_ns(), 60_000);
    assert_eq!(st.jitter.abs().count(), 2);
}
