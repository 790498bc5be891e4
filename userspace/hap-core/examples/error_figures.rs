//! Print the fixed-point vs f64 error figures (`cargo run -p hap-core --example error_figures`).
use hap_core::fixed::Fx;
use rand::{Rng, SeedableRng};

fn main() {
    let mut r = rand::rngs::StdRng::seed_from_u64(1);
    let (mut es, mut ea, mut eq, mut ed) = (0f64, 0f64, 0f64, 0f64);
    for _ in 0..1_000_000 {
        let x: f64 = r.gen_range(-1e4..1e4);
        let (s, c) = Fx::from_f64(x).sin_cos();
        let xr = Fx::from_f64(x).to_f64();
        es = es
            .max((s.to_f64() - libm::sin(xr)).abs())
            .max((c.to_f64() - libm::cos(xr)).abs());
        let (a, b): (f64, f64) = (r.gen_range(-1e3..1e3), r.gen_range(-1e3..1e3));
        let (fa, fb) = (Fx::from_f64(a), Fx::from_f64(b));
        ea = ea.max((Fx::atan2(fa, fb).to_f64() - libm::atan2(fa.to_f64(), fb.to_f64())).abs());
        let v: f64 = r.gen_range(0.0..1e6);
        let fv = Fx::from_f64(v);
        eq = eq.max((fv.sqrt().to_f64() - fv.to_f64().sqrt()).abs() / fv.to_f64().sqrt().max(1e-9));
        let d = r.gen_range(0.01..100.0);
        let fd = Fx::from_f64(d);
        ed = ed.max(((fa / fd).to_f64() - fa.to_f64() / fd.to_f64()).abs());
    }
    println!("sin/cos |x|<=1e4: max abs err {es:.2e}");
    println!("atan2: max abs err {ea:.2e} rad");
    println!("sqrt: max rel err {eq:.2e}");
    println!("div: max abs err {ed:.2e}");
    println!("kinematics and 10 s dynamics vs the nalgebra reference: cargo test -p hap-core --test dynamics -- --nocapture");
}
