//! Link passivity through the public API: the controller and a client
//! across a delayed, jittery, lossy, reordering channel (a small seed set;
//! the full campaign is `scripts/bench-link-passivity.sh`).

#[path = "common/campaign.rs"]
mod campaign;
#[path = "common/link_campaign.rs"]
mod link_campaign;

use link_campaign::{force_bound, probe_wall, run, Link, Object};

fn link(rtt_ms: f64, jitter: f64, loss: f64, object: Object) -> Link {
    Link {
        rtt_ms,
        jitter,
        loss,
        passivity: true,
        object,
    }
}

#[test]
fn slow_link_stays_coupled_and_the_channel_creates_no_energy() {
    for (seed, rtt, jitter, loss) in [
        (1u64, 0.0, 0.0, 0.0),
        (2, 20.0, 0.5, 0.1),
        (3, 100.0, 0.5, 0.2),
        (4, 300.0, 0.5, 0.1),
        (5, 1000.0, 0.5, 0.2),
    ] {
        for object in [Object::FreeMass, Object::Wall] {
            let l = link(rtt, jitter, loss, object);
            let r = run(seed, l, 6000);
            println!("{l:?}: {r:?}");
            assert_eq!(r.faded_cycles, 0, "a live link faded: {l:?}");
            assert!(r.coupled_cycles > 4000, "{l:?}: {r:?}");
            assert!(
                r.channel_min >= -1e-4,
                "channel created energy: {l:?}: {r:?}"
            );
            assert!(r.max_force <= force_bound() * (1.0 + 1e-6), "{r:?}");
            assert!(
                r.max_speed <= campaign::handle_speed_bound(1_000_000),
                "{r:?}"
            );
            assert!(
                r.release_end <= r.release_peak * 1.05 + 1e-6,
                "oscillation grew after release: {l:?}: {r:?}"
            );
        }
    }
}

#[test]
fn the_wall_is_felt_at_300_ms_and_the_handle_returns_to_the_object() {
    for rtt in [0.0, 300.0] {
        let p = probe_wall(rtt, 0.5, 0.1, true, 11);
        println!("rtt {rtt} ms: {p:?}");
        assert!(p.channel_min >= -1e-4, "{p:?}");
        // A wall: stiffer than the user's hold alone, and the handle stops
        // within a few centimetres of it under 10 N.
        assert!(p.stiffness > 300.0, "{p:?}");
        assert!(p.penetration_10n < 0.05, "{p:?}");
    }
}

#[test]
fn without_passivity_a_slow_link_creates_energy() {
    // The same run with both controllers off: the channel's ledger (its
    // observers run all the same) goes below zero. Shows that the ledger
    // can fail, and what the controllers prevent.
    let l = Link {
        rtt_ms: 300.0,
        jitter: 0.5,
        loss: 0.1,
        passivity: false,
        object: Object::FreeMass,
    };
    let r = run(4, l, 6000);
    println!("{r:?}");
    assert!(r.channel_min < -0.01, "{r:?}");
}
