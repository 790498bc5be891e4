//! One run of the safety campaign (debugging): safety_one SEED PERIOD_US CYCLES
#[path = "../tests/common/campaign.rs"]
mod campaign;

fn main() {
    let a: Vec<u64> = std::env::args()
        .skip(1)
        .filter_map(|x| x.parse().ok())
        .collect();
    let (seed, us, cycles) = match a.as_slice() {
        [s, p, c] => (*s, *p as u32, *c),
        _ => {
            eprintln!("usage: safety_one SEED PERIOD_US CYCLES");
            std::process::exit(2);
        }
    };
    campaign::run(seed, us, cycles).print(&format!("seed {seed}, {us} µs"));
}
