//! The full safety campaign (≥ 10^6 cycles through `ServoCycle::run`, at
//! 250 µs, 1 ms, 10 ms and 100 µs, the shortest period; the seeds of the
//! first three do not depend on the fourth); `scripts/bench-safety.sh` runs it in release.
//! Usage: safety_campaign [RUNS_PER_PERIOD] [CYCLES_PER_RUN]
#[path = "../tests/common/campaign.rs"]
mod campaign;

fn main() {
    let mut args = std::env::args().skip(1);
    let runs: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(12);
    let cycles: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(30_000);
    let mut all = campaign::Figures::new();
    for (i, &us) in [250u32, 1000, 10_000, 100].iter().enumerate() {
        let mut per = campaign::Figures::new();
        for seed in 0..runs {
            let sd = 1000 + seed * 7 + i as u64;
            let figs = campaign::run(sd, us, cycles);
            if figs.worst_ledger < -1e-6 || figs.worst_observer < -1e-6 {
                println!(
                    "  seed {sd} at {us} µs: ledger {:.3e} J, observer {:.3e} J",
                    figs.worst_ledger, figs.worst_observer
                );
            }
            per.merge(&figs);
        }
        per.print(&format!("{us} µs"));
        all.merge(&per);
    }
    all.print("all periods");
}
