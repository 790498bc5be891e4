//! A ros2-client subscriber of the node's pose that measures, for every
//! sample, its arrival time minus its stamp (the system clock when the node
//! took the controller's answer): the DDS-added latency without a Python
//! peer's own delays (scripts/bench-ros2.sh runs it next to the Cyclone peer).
//!
//!   latency_probe DOMAIN NAMESPACE SECONDS
//!
//! Prints `probe.samples`, `probe.latency_us_p50`, `_p99`, `_max` as
//! `key: value` lines.

use std::time::{Duration, Instant};

use hapticctrl_ros2::msgs::{self, MsgType, PoseStamped};
use ros2_client::builtin_interfaces::Time;
use ros2_client::qos::{Durability, History, Reliability};
use ros2_client::{Context, Name, NodeName, NodeOptions, QosProfile};
use rustdds::mio1::{Events, Interest, Poll, Token};
use rustdds::DomainParticipantBuilder;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = || -> ! {
        eprintln!("usage: latency_probe DOMAIN NAMESPACE SECONDS");
        std::process::exit(2)
    };
    let [domain, ns, secs] = args.as_slice() else {
        usage()
    };
    let domain: u16 = domain.parse().unwrap_or_else(|_| usage());
    let secs: f64 = secs.parse().unwrap_or_else(|_| usage());
    let dp = DomainParticipantBuilder::new(domain)
        .with_only_networks([std::net::IpAddr::from([127, 0, 0, 1])])
        .build()
        .unwrap_or_else(|e| {
            eprintln!("latency_probe: participant: {e:?}");
            std::process::exit(1)
        });
    let ctx = Context::from_domain_participant(dp).expect("context");
    let mut node = ctx
        .new_node(
            NodeName::new(ns, "latency_probe").expect("node name"),
            NodeOptions::new().enable_rosout(false),
        )
        .expect("node");
    let qos = QosProfile::subscription_default()
        .reliability(Reliability::BestEffort)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 64 });
    let topic = node
        .create_topic(
            &Name::new(ns, "pose").expect("name"),
            msgs::type_name(MsgType::PoseStamped),
            &qos,
        )
        .expect("topic");
    let mut sub = node
        .create_subscription::<PoseStamped>(&topic, None)
        .expect("subscription");
    let mut poll = Poll::new().expect("poll");
    poll.registry()
        .register(&mut sub, Token(1), Interest::READABLE)
        .expect("register");
    let mut events = Events::with_capacity(8);
    let end = Instant::now() + Duration::from_secs_f64(secs);
    let mut lat_us: Vec<f64> = Vec::new();
    while Instant::now() < end {
        let _ = poll.poll(&mut events, Some(Duration::from_millis(50)));
        while let Ok(Some((m, _))) = sub.take() {
            let now = Time::now().to_nanos();
            lat_us.push((now - m.header.stamp.to_nanos()) as f64 / 1e3);
        }
    }
    lat_us.sort_by(f64::total_cmp);
    let pct = |p: f64| {
        lat_us
            .get(((p / 100.0) * lat_us.len() as f64) as usize)
            .or(lat_us.last())
            .copied()
            .unwrap_or(f64::NAN)
    };
    println!("probe.samples: {}", lat_us.len());
    println!("probe.latency_us_p50: {:.1}", pct(50.0));
    println!("probe.latency_us_p99: {:.1}", pct(99.0));
    println!("probe.latency_us_max: {:.1}", pct(100.0));
}
