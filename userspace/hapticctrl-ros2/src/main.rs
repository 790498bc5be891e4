//! hapticctrl-ros2: one ROS 2 node per arm (see the crate's documentation
//! and Documentation/userguide.md, "hapticctrl-ros2").
//!
//! Publishes (relative to the node's namespace):
//!   pose          geometry_msgs/PoseStamped   handle pose          best effort, keep last N
//!   twist         geometry_msgs/TwistStamped  handle twist         best effort, keep last N
//!   wrench        geometry_msgs/WrenchStamped coupling wrench      best effort, keep last N
//!   joint_states  sensor_msgs/JointState      joint angles, speeds best effort, keep last N
//!   buttons       sensor_msgs/Joy             buttons 1 and 2      reliable, keep last 1
//!   status        diagnostic_msgs/DiagnosticStatus                 reliable, keep last 1
//! Subscribes:
//!   target_pose   geometry_msgs/PoseStamped   virtual-object pose  best effort, keep last 1
//!   target_twist  geometry_msgs/TwistStamped  virtual-object twist best effort, keep last 1
//!   force_command geometry_msgs/WrenchStamped added wrench         best effort, keep last 1
//! Service:
//!   set_power     std_srvs/SetBool            arm power on / off
//! Parameter (rcl_interfaces' parameter services):
//!   command_type  string: none, impedance or virtmech

use std::net::IpAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::{Parser, ValueEnum};
use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::{
    Context, Name, Node, NodeName, NodeOptions, ParameterValue, Publisher, QosProfile, Server,
    ServiceMapping, Subscription,
};
use rustdds::DomainParticipantBuilder;

use hap_core::control::Gains;
use hap_core::fixed::Fx;
use hapticctrl_ros2::msgs::{
    self, header_now, DiagnosticStatus, JointState, Joy, MsgType, PoseStamped, SetBoolRequest,
    SetBoolResponse, Twist, TwistStamped, Wrench, WrenchStamped,
};
use hapticctrl_ros2::{
    buttons, ended_report, joint_names, setpoint, stale_report, status_report, STALE_AFTER,
};
use virtuose_api::kin::{self, Frames};
use virtuose_api::{CommandType, VirtContext, VirtError};

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
#[value(rename_all = "lower")]
enum CommandTypeArg {
    /// No coupling: the arm is free.
    None,
    /// Cartesian impedance: the handle is coupled to the streamed set-point.
    Impedance,
    /// Virtual mechanism: a virtual object of `--vo-mass` kg.
    Virtmech,
}

impl CommandTypeArg {
    fn command(self) -> CommandType {
        match self {
            CommandTypeArg::None => CommandType::None,
            CommandTypeArg::Impedance => CommandType::Impedance,
            CommandTypeArg::Virtmech => CommandType::VirtMech,
        }
    }

    /// The value of the `command_type` parameter.
    fn name(self) -> &'static str {
        match self {
            CommandTypeArg::None => "none",
            CommandTypeArg::Impedance => "impedance",
            CommandTypeArg::Virtmech => "virtmech",
        }
    }

    fn from_parameter(v: &ParameterValue) -> Result<CommandTypeArg, String> {
        match v {
            ParameterValue::String(s) => CommandTypeArg::from_str(s, false)
                .map_err(|_| format!("command_type {s:?}: none, impedance or virtmech")),
            other => Err(format!("command_type must be a string, got {other:?}")),
        }
    }
}

/// ROS 2 node for one hapticctrl arm (no ROS installation needed).
#[derive(Parser, Debug)]
#[command(name = "hapticctrl-ros2", version)]
struct Cli {
    /// Controller address, "host#port" (virtuose_api's form).
    #[arg(long, default_value = "127.0.0.1#5000")]
    server: String,
    /// Pre-shared key file (authenticated bridge, protocol v2).
    #[arg(long)]
    key: Option<PathBuf>,
    /// ROS 2 node name.
    #[arg(long, default_value = "hapticctrl")]
    node_name: String,
    /// ROS 2 namespace of the node and its topics (one per arm, e.g. /left).
    #[arg(long, default_value = "/hapticctrl")]
    namespace: String,
    /// Publication rate in Hz; 0: every answer of the controller.
    #[arg(long, default_value_t = 0.0)]
    rate: f64,
    /// frame_id of the pose, twist, wrench and set-points (the
    /// controller's world frame).
    #[arg(long, default_value = "hapticctrl_base")]
    frame_id: String,
    /// Prefix of the joint names (PREFIXjoint1..6); default: NODE_NAME_.
    #[arg(long)]
    joint_prefix: Option<String>,
    /// DDS domain id.
    #[arg(long, env = "ROS_DOMAIN_ID", default_value_t = 0)]
    domain_id: u16,
    /// Only this local address in DDS discovery announcements and for
    /// multicast, e.g. 127.0.0.1 (the sockets still bind to all addresses).
    #[arg(long)]
    dds_address: Option<IpAddr>,
    /// Command type set at start.
    #[arg(long, value_enum, default_value_t = CommandTypeArg::Impedance)]
    command_type: CommandTypeArg,
    /// Virtual-object mass, kg (virtmech).
    #[arg(long, default_value_t = 0.5)]
    vo_mass: f32,
    /// Power the arm on at start.
    #[arg(long)]
    power_on: bool,
    /// History depth of the streaming writers (pose, twist, wrench, joints).
    #[arg(long, default_value_t = 16)]
    depth: usize,
    /// A set-point older than this is no longer streamed, ms.
    #[arg(long, default_value_t = 100)]
    setpoint_timeout_ms: u64,
    /// Status and buttons are published on change and at this rate, Hz.
    #[arg(long, default_value_t = 10.0)]
    status_rate: f64,
    /// Stop after this many seconds and print the node's statistics (0: run
    /// until killed).
    #[arg(long, default_value_t = 0.0)]
    duration: f64,
}

/// Longest silence towards the controller (a third of the bridge's default
/// session timeout).
const KEEPALIVE: Duration = Duration::from_secs(1);

/// The node's counters, printed at the end as `key: value` lines.
#[derive(Debug, Default)]
struct Counters {
    answers: u64,
    published: u64,
    publish_errors: u64,
    joint_states: u64,
    out_of_reach: u64,
    status_published: u64,
    targets: u64,
    twists: u64,
    wrenches: u64,
    rejected: u64,
    setpoints_streamed: u64,
    stream_errors: u64,
    power_requests: u64,
    command_type_changes: u64,
    command_type_errors: u64,
    keepalives: u64,
}

struct Publishers {
    pose: Publisher<PoseStamped>,
    twist: Publisher<TwistStamped>,
    wrench: Publisher<WrenchStamped>,
    joints: Publisher<JointState>,
    buttons: Publisher<Joy>,
    status: Publisher<DiagnosticStatus>,
}

struct Subscriptions {
    target_pose: Subscription<PoseStamped>,
    target_twist: Subscription<TwistStamped>,
    force_command: Subscription<WrenchStamped>,
}

/// Streaming: samples may be lost, the newest counts. A depth above 1 keeps
/// a burst of samples published between two runs of RustDDS's event loop
/// instead of overwriting all but the last (Documentation/userguide.md,
/// "hapticctrl-ros2", QoS).
fn streaming_qos(depth: usize) -> QosProfile {
    QosProfile::subscription_default()
        .reliability(Reliability::BestEffort)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth })
}

/// Set-points: only the newest matters.
fn setpoint_qos() -> QosProfile {
    streaming_qos(1)
}

/// Status and buttons: reliable, the last one kept for late joiners; a full
/// send window fails at once (counted) instead of stalling the loop.
fn status_qos() -> QosProfile {
    QosProfile::publisher_default()
        .reliability(Reliability::Reliable {
            when_full: WhenFull::Fail,
        })
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 })
}

/// Services: ROS 2's default for services (reliable, volatile, keep last
/// 10), which clients of every ROS 2 implementation request.
fn service_qos() -> QosProfile {
    QosProfile::publisher_default()
        .reliability(Reliability::Reliable {
            when_full: WhenFull::Fail,
        })
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 10 })
}

fn ros_err(what: &str, e: impl std::fmt::Debug) -> String {
    format!("{what}: {e:?}")
}

fn create_publisher<M: serde::Serialize>(
    node: &mut Node,
    topic: &str,
    ty: MsgType,
    qos: &QosProfile,
) -> Result<Publisher<M>, String> {
    let name = Name::new("", topic).map_err(|e| ros_err(topic, e))?;
    let t = node
        .create_topic(&name, msgs::type_name(ty), qos)
        .map_err(|e| ros_err(topic, e))?;
    node.create_publisher(&t, None)
        .map_err(|e| ros_err(topic, e))
}

fn create_subscription<M: 'static>(
    node: &mut Node,
    topic: &str,
    ty: MsgType,
    qos: &QosProfile,
) -> Result<Subscription<M>, String> {
    let name = Name::new("", topic).map_err(|e| ros_err(topic, e))?;
    let t = node
        .create_topic(&name, msgs::type_name(ty), qos)
        .map_err(|e| ros_err(topic, e))?;
    node.create_subscription(&t, None)
        .map_err(|e| ros_err(topic, e))
}

/// One answer of the controller, read consistently (the same servo cycle
/// before and after).
struct Snapshot {
    pose: [f32; 7],
    twist: [f32; 6],
    wrench: [f32; 6],
    status: u32,
    alarms: u32,
    cycle: u32,
}

fn snapshot(vc: &VirtContext) -> Result<Snapshot, VirtError> {
    for _ in 0..4 {
        let cycle = vc.get_cycle()?;
        let s = Snapshot {
            pose: vc.get_position()?,
            twist: vc.get_speed()?,
            wrench: vc.get_force()?,
            status: vc.get_status()?,
            alarms: vc.get_alarm()?,
            cycle,
        };
        if vc.get_cycle()? == cycle {
            return Ok(s);
        }
    }
    Err(VirtError::Timeout("a consistent answer"))
}

/// CPU time of this process (all threads), s, from /proc/self/stat
/// (utime + stime in clock ticks of 1/100 s).
fn cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    // After the command: state is field 3, utime 14, stime 15.
    let ut: f64 = f.get(11)?.parse().ok()?;
    let st: f64 = f.get(12)?.parse().ok()?;
    Some((ut + st) / 100.0)
}

/// The newest valid sample of a subscription (all waiting ones are taken;
/// malformed ones counted in `rejected`).
fn take_newest<M: 'static + serde::de::DeserializeOwned, T>(
    sub: &Subscription<M>,
    rejected: &mut u64,
    mut convert: impl FnMut(&M) -> Option<T>,
) -> (u64, Option<T>) {
    let mut n = 0;
    let mut newest = None;
    // Bounded: a flood cannot keep the loop here.
    for _ in 0..256 {
        match sub.take() {
            Ok(Some((m, _info))) => match convert(&m) {
                Some(v) => {
                    n += 1;
                    newest = Some(v);
                }
                None => *rejected += 1,
            },
            Ok(None) => break,
            Err(_) => *rejected += 1,
        }
    }
    (n, newest)
}

/// Set the command type (attaching the virtual object for virtmech) and
/// return the coupling spring the controller then applies, (N/m, N·m/rad):
/// its gains for the servo period, in virtmech capped at m/ts² as the
/// controller does.
fn apply_command_type(
    vc: &VirtContext,
    ct: CommandTypeArg,
    vo_mass: f32,
    period_us: u32,
) -> Result<(f64, f64), String> {
    let command = ct.command();
    vc.set_command_type(command)
        .map_err(|e| format!("set command type {}: {e}", ct.name()))?;
    let gains = Gains::for_period(Fx::from_ratio(period_us as i64, 1_000_000));
    let mut k_lin = gains.k_lin.to_f64();
    if command == CommandType::VirtMech {
        vc.attach_vo(vo_mass, [1e-3; 3])
            .map_err(|e| format!("attach virtual object: {e}"))?;
        let ts = period_us as f64 * 1e-6;
        k_lin = k_lin.min(vo_mass as f64 / (ts * ts));
    }
    Ok((k_lin, gains.k_rot.to_f64()))
}

fn run(cli: Cli) -> Result<(), String> {
    if !(cli.rate.is_finite() && (0.0..=10_000.0).contains(&cli.rate)) {
        return Err(format!("--rate {}: 0 (every answer) to 10000 Hz", cli.rate));
    }
    if !(cli.status_rate.is_finite() && cli.status_rate > 0.0 && cli.status_rate <= 1000.0) {
        return Err(format!("--status-rate {}: (0, 1000] Hz", cli.status_rate));
    }
    if !(cli.duration.is_finite() && cli.duration >= 0.0) {
        return Err(format!("--duration {}: seconds >= 0", cli.duration));
    }
    if cli.depth == 0 || cli.depth > 1024 {
        return Err(format!("--depth {}: 1..1024", cli.depth));
    }
    if cli.domain_id > 232 {
        return Err(format!("--domain-id {}: 0..232", cli.domain_id));
    }
    if !(cli.vo_mass.is_finite() && cli.vo_mass > 0.0) {
        return Err(format!("--vo-mass {}: kg > 0", cli.vo_mass));
    }
    let node_name = NodeName::new(&cli.namespace, &cli.node_name)
        .map_err(|e| format!("node name {:?} in {:?}: {e}", cli.node_name, cli.namespace))?;
    let joint_prefix = cli
        .joint_prefix
        .clone()
        .unwrap_or_else(|| format!("{}_", cli.node_name));

    // ---- the controller
    let address = match &cli.key {
        Some(k) => format!("{}?key={}", cli.server, k.display()),
        None => cli.server.clone(),
    };
    let mut vc =
        VirtContext::open(&address).map_err(|e| format!("connect to {}: {e}", cli.server))?;
    let period_us = vc.link_stats().period_us.max(1);
    let ts = period_us as f32 * 1e-6;
    vc.set_time_step(ts)
        .map_err(|e| format!("set time step: {e}"))?;
    let (mut k_lin, k_rot) = apply_command_type(&vc, cli.command_type, cli.vo_mass, period_us)?;
    let mut command_type = cli.command_type;
    if cli.power_on {
        vc.set_power_on(true)
            .map_err(|e| format!("power on: {e}"))?;
    }

    // ---- the ROS 2 node
    let mut dp = DomainParticipantBuilder::new(cli.domain_id);
    if let Some(a) = cli.dds_address {
        dp = dp.with_only_networks([a]);
    }
    let dp = dp.build().map_err(|e| ros_err("DDS participant", e))?;
    let context = Context::from_domain_participant(dp).map_err(|e| ros_err("ROS 2 context", e))?;
    // The command_type parameter: validated here, applied by the loop.
    let (command_tx, command_rx) = std::sync::mpsc::channel::<CommandTypeArg>();
    let command_tx = std::sync::Mutex::new(command_tx);
    let options = NodeOptions::new()
        .enable_rosout(false)
        .start_parameter_services(true)
        .declare_parameter(
            "command_type",
            ParameterValue::String(cli.command_type.name().into()),
        )
        .parameter_validator(Box::new(|name, value| match name {
            "command_type" => CommandTypeArg::from_parameter(value).map(|_| ()),
            _ => Ok(()),
        }))
        .parameter_set_action(Box::new(move |name, value| {
            if name == "command_type" {
                let c = CommandTypeArg::from_parameter(value)?;
                let tx = command_tx.lock().map_err(|_| "node stopping".to_owned())?;
                tx.send(c).map_err(|_| "node stopping".to_owned())?;
            }
            Ok(())
        }));
    let mut node = context
        .new_node(node_name, options)
        .map_err(|e| ros_err("ROS 2 node", e))?;
    // The parameter services run in the node's spinner.
    let spinner = node.spinner().map_err(|e| ros_err("ROS 2 spinner", e))?;
    std::thread::Builder::new()
        .name("ros2-spinner".into())
        .spawn(move || futures::executor::block_on(spinner.spin()))
        .map_err(|e| format!("spinner thread: {e}"))?;
    let sq = streaming_qos(cli.depth);
    let pubs = Publishers {
        pose: create_publisher(&mut node, "pose", MsgType::PoseStamped, &sq)?,
        twist: create_publisher(&mut node, "twist", MsgType::TwistStamped, &sq)?,
        wrench: create_publisher(&mut node, "wrench", MsgType::WrenchStamped, &sq)?,
        joints: create_publisher(&mut node, "joint_states", MsgType::JointState, &sq)?,
        buttons: create_publisher(&mut node, "buttons", MsgType::Joy, &status_qos())?,
        status: create_publisher(
            &mut node,
            "status",
            MsgType::DiagnosticStatus,
            &status_qos(),
        )?,
    };
    let spq = setpoint_qos();
    let subs = Subscriptions {
        target_pose: create_subscription(&mut node, "target_pose", MsgType::PoseStamped, &spq)?,
        target_twist: create_subscription(&mut node, "target_twist", MsgType::TwistStamped, &spq)?,
        force_command: create_subscription(
            &mut node,
            "force_command",
            MsgType::WrenchStamped,
            &spq,
        )?,
    };
    let power_service: Server<SetBoolRequest, SetBoolResponse> = node
        .create_server(
            ServiceMapping::Enhanced,
            &Name::new("", "set_power").map_err(|e| ros_err("set_power", e))?,
            &msgs::set_bool_type(),
            service_qos(),
            service_qos(),
        )
        .map_err(|e| ros_err("set_power service", e))?;
    eprintln!(
        "hapticctrl-ros2: node {} on DDS domain {}, controller {} (servo period {} us)",
        node.fully_qualified_name(),
        cli.domain_id,
        vc.peer(),
        period_us
    );

    let names = joint_names(&joint_prefix);
    let frames = Frames::default();
    let hardware_id = cli.server.clone();
    let status_name = node.fully_qualified_name();
    let fixed_period = (cli.rate > 0.0).then(|| Duration::from_secs_f64(1.0 / cli.rate));
    let status_period = Duration::from_secs_f64(1.0 / cli.status_rate);
    let setpoint_timeout = Duration::from_millis(cli.setpoint_timeout_ms);
    let waiter = vc.answer_waiter();
    let (mut gen, _) = waiter.current();
    let mut c = Counters::default();
    let mut last_q: Option<[f64; 6]> = None;
    let mut last_status: Option<(u32, u32)> = None;
    let mut last_buttons: Option<Vec<i32>> = None;
    let mut next_status = Instant::now();
    let mut next_tick = Instant::now();
    let mut target: Option<([f32; 7], Instant)> = None;
    let mut target_twist: Option<([f32; 6], Instant)> = None;
    let mut added_wrench: Option<([f32; 6], Instant)> = None;
    let t_start = Instant::now();
    let mut last_sent = t_start;
    let mut last_answer_at = t_start;
    let mut stale = false;
    let cpu_start = cpu_seconds();
    let end = (cli.duration > 0.0).then(|| t_start + Duration::from_secs_f64(cli.duration));

    loop {
        if end.is_some_and(|e| Instant::now() >= e) {
            break;
        }
        // ---- the session: if the controller ended it (another key holder
        // took the arm, it expired, its numbers are spent, a fail-safe),
        // the node says so on its status and stops with the error.
        let session_ended = |e: &VirtError| {
            let code = virtuose_api::ffi::haption_code(e);
            let _ = pubs
                .status
                .publish(ended_report(&status_name, &hardware_id, e, code));
            format!("{e} (VirtuoseAPI error {code})")
        };
        if let Err(e) = vc.check_session() {
            return Err(session_ended(&e));
        }
        // ---- wait for the next answer (or the next tick of a set rate)
        let fresh = match fixed_period {
            None => match waiter.wait_newer(gen, Duration::from_millis(50)) {
                Some((g, _)) => {
                    gen = g;
                    last_answer_at = Instant::now();
                    true
                }
                None => false,
            },
            Some(p) => {
                let now = Instant::now();
                if next_tick > now {
                    std::thread::sleep(next_tick - now);
                }
                next_tick += p;
                if next_tick < Instant::now() {
                    next_tick = Instant::now() + p;
                }
                // The newest answer, again if no newer one came, until the
                // controller has been silent for STALE_AFTER.
                let (g, _) = waiter.current();
                if g != gen {
                    gen = g;
                    last_answer_at = Instant::now();
                }
                g != 0 && last_answer_at.elapsed() < STALE_AFTER
            }
        };

        // ---- power requests (acknowledged by the controller: may block
        // this loop for the request's timeout)
        while let Ok(Some((id, req))) = power_service.receive_request() {
            c.power_requests += 1;
            let r = vc.set_power_on(req.data);
            let resp = SetBoolResponse {
                success: r.is_ok(),
                message: match r {
                    Ok(()) => format!("power {}", if req.data { "on" } else { "off" }),
                    Err(e) => e.to_string(),
                },
            };
            if power_service.send_response(id, resp).is_err() {
                c.publish_errors += 1;
            }
        }

        while let Ok(ct) = command_rx.try_recv() {
            if ct == command_type {
                continue;
            }
            match apply_command_type(&vc, ct, cli.vo_mass, period_us) {
                Ok((k, _)) => {
                    k_lin = k;
                    command_type = ct;
                    c.command_type_changes += 1;
                }
                Err(e) => {
                    eprintln!("hapticctrl-ros2: {e}");
                    c.command_type_errors += 1;
                }
            }
        }

        if !fresh {
            // No answer for a while: the status says so once (level STALE),
            // the last state stays what subscribers have.
            if !stale && last_answer_at.elapsed() >= STALE_AFTER {
                stale = true;
                let r = pubs.status.publish(stale_report(
                    &status_name,
                    &hardware_id,
                    last_answer_at.elapsed(),
                ));
                match r {
                    Ok(()) => c.status_published += 1,
                    Err(_) => c.publish_errors += 1,
                }
                last_status = None;
            }
            continue;
        }
        let s = match snapshot(&vc) {
            Ok(s) => s,
            Err(VirtError::NoData) => continue,
            Err(e @ VirtError::SessionEnded { .. }) => return Err(session_ended(&e)),
            Err(e) => return Err(format!("reading the controller's answer: {e}")),
        };
        c.answers += 1;
        stale = false;

        // ---- publish the arm's state, all with the same stamp
        let header = header_now(&cli.frame_id);
        let (lin, ang) = msgs::split6(&s.twist);
        let (force, torque) = msgs::split6(&s.wrench);
        let mut ok = [
            pubs.pose
                .publish(PoseStamped {
                    header: header.clone(),
                    pose: msgs::pose_from_array(&s.pose),
                })
                .is_ok(),
            pubs.twist
                .publish(TwistStamped {
                    header: header.clone(),
                    twist: Twist {
                        linear: lin,
                        angular: ang,
                    },
                })
                .is_ok(),
            pubs.wrench
                .publish(WrenchStamped {
                    header: header.clone(),
                    wrench: Wrench { force, torque },
                })
                .is_ok(),
        ]
        .to_vec();
        let phys = frames.physical_pose(&s.pose);
        match kin::inverse_kinematics(&phys, last_q.as_ref()) {
            Some(q) => {
                last_q = Some(q);
                let qd = kin::joint_speeds(&q, &frames.physical_twist(&s.twist));
                ok.push(
                    pubs.joints
                        .publish(JointState {
                            header: header.clone(),
                            name: names.clone(),
                            position: q.to_vec(),
                            velocity: qd.to_vec(),
                            effort: Vec::new(),
                        })
                        .is_ok(),
                );
                c.joint_states += 1;
            }
            None => c.out_of_reach += 1,
        }
        for o in ok {
            if o {
                c.published += 1;
            } else {
                c.publish_errors += 1;
            }
        }
        let now = Instant::now();
        let b = buttons(s.status);
        if last_buttons.as_ref() != Some(&b) || now >= next_status {
            let r = pubs.buttons.publish(Joy {
                header: header.clone(),
                axes: Vec::new(),
                buttons: b.clone(),
            });
            if r.is_err() {
                c.publish_errors += 1;
            }
            last_buttons = Some(b);
        }
        if last_status != Some((s.status, s.alarms)) || now >= next_status {
            let r = pubs.status.publish(status_report(
                &status_name,
                &hardware_id,
                s.status,
                s.alarms,
                s.cycle,
            ));
            match r {
                Ok(()) => c.status_published += 1,
                Err(_) => c.publish_errors += 1,
            }
            last_status = Some((s.status, s.alarms));
            next_status = now + status_period;
        }

        // ---- set-points from the subscriptions
        let (n, t) = take_newest(&subs.target_pose, &mut c.rejected, |m: &PoseStamped| {
            msgs::pose_to_array(&m.pose)
        });
        c.targets += n;
        if let Some(t) = t {
            target = Some((t, now));
        }
        let (n, t) = take_newest(&subs.target_twist, &mut c.rejected, |m: &TwistStamped| {
            msgs::join6(&m.twist.linear, &m.twist.angular)
        });
        c.twists += n;
        if let Some(t) = t {
            target_twist = Some((t, now));
        }
        let (n, w) = take_newest(&subs.force_command, &mut c.rejected, |m: &WrenchStamped| {
            msgs::join6(&m.wrench.force, &m.wrench.torque)
        });
        c.wrenches += n;
        if let Some(w) = w {
            added_wrench = Some((w, now));
        }
        target = target.filter(|(_, at)| now - *at <= setpoint_timeout);
        target_twist = target_twist.filter(|(_, at)| now - *at <= setpoint_timeout);
        added_wrench = added_wrench.filter(|(_, at)| now - *at <= setpoint_timeout);
        if let Some(sp) = setpoint(
            &frames,
            &s.pose,
            target.as_ref().map(|(t, _)| t),
            added_wrench.as_ref().map(|(w, _)| w),
            k_lin,
            k_rot,
        ) {
            let twist = target_twist.map(|(t, _)| t).unwrap_or([0.0; 6]);
            match vc.set_speed(&twist).and_then(|()| vc.set_position(&sp)) {
                Ok(()) => {
                    c.setpoints_streamed += 1;
                    last_sent = Instant::now();
                }
                Err(_) => c.stream_errors += 1,
            }
        }
        // The bridge closes a session its client leaves silent for its
        // --session-timeout-ms (3 s by default): without set-points to
        // stream, the node re-sends its time step (acknowledged, changes
        // nothing) every KEEPALIVE.
        if last_sent.elapsed() >= KEEPALIVE {
            match vc.set_time_step(ts) {
                Ok(()) => c.keepalives += 1,
                Err(_) => c.stream_errors += 1,
            }
            last_sent = Instant::now();
        }
    }

    let wall = t_start.elapsed().as_secs_f64();
    let cpu = match (cpu_start, cpu_seconds()) {
        (Some(a), Some(b)) => b - a,
        _ => f64::NAN,
    };
    let link = vc.link_stats();
    let _ = vc.close();
    println!("wall_s: {wall:.3}");
    println!("cpu_s: {cpu:.3}");
    println!("answers: {}", c.answers);
    println!("answer_rate_hz: {:.1}", c.answers as f64 / wall.max(1e-9));
    println!("published: {}", c.published);
    println!("joint_states: {}", c.joint_states);
    println!("out_of_reach: {}", c.out_of_reach);
    println!("status_published: {}", c.status_published);
    println!("publish_errors: {}", c.publish_errors);
    println!("targets: {}", c.targets);
    println!("target_twists: {}", c.twists);
    println!("wrenches: {}", c.wrenches);
    println!("rejected: {}", c.rejected);
    println!("setpoints_streamed: {}", c.setpoints_streamed);
    println!("stream_errors: {}", c.stream_errors);
    println!("power_requests: {}", c.power_requests);
    println!("command_type_changes: {}", c.command_type_changes);
    println!("command_type_errors: {}", c.command_type_errors);
    println!("keepalives: {}", c.keepalives);
    println!("link_lost: {}", link.lost);
    println!(
        "cpu_us_per_answer: {:.1}",
        cpu * 1e6 / (c.answers.max(1) as f64)
    );
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("hapticctrl-ros2: {e}");
            ExitCode::from(1)
        }
    }
}
