//! hapticctrl-ros2: a ROS 2 node for one hapticctrl arm, on `ros2-client`
//! (RustDDS: ROS 2's DDS wire protocol without a ROS installation), talking
//! to the controller through `virtuose_api`.
//!
//! The pieces that do not need a DDS participant live here so that they
//! are tested on their own: the message layouts ([`msgs`]), the status
//! report, the buttons, and the coupling set-point from the subscribed
//! target and added wrench ([`setpoint`]).

pub mod msgs;

use hap_core::vp::{alarm, status};
use virtuose_api::kin::{self, Frames};

use msgs::{DiagnosticStatus, KeyValue};

/// The handle's buttons as `sensor_msgs/Joy` buttons: `[button 1, button 2]`.
pub fn buttons(status_bits: u32) -> Vec<i32> {
    vec![
        (status_bits & status::BUTTON_1 != 0) as i32,
        (status_bits & status::BUTTON_2 != 0) as i32,
    ]
}

/// The status bits the node reports, in the order of the report's values.
const STATUS_NAMES: [(u32, &str); 10] = [
    (status::POWER_ON, "power_on"),
    (status::MOTORS_ENABLED, "motors_enabled"),
    (status::DEAD_MAN, "dead_man"),
    (status::EMERGENCY_STOP, "emergency_stop"),
    (status::BUTTON_1, "button_1"),
    (status::BUTTON_2, "button_2"),
    (status::DEGRADED, "degraded"),
    (status::COUPLED, "coupled"),
    (status::LINK_FADING, "link_fading"),
    (status::VPR_EXTRAPOLATED, "setpoint_extrapolated"),
];

/// The alarm bits, by name.
const ALARM_NAMES: [(u32, &str); 6] = [
    (alarm::JOINT_LIMIT, "joint_limit"),
    (alarm::TORQUE_SATURATED, "torque_saturated"),
    (alarm::VELOCITY_LIMIT, "velocity_limit"),
    (alarm::PASSIVITY, "passivity"),
    (alarm::DEADLINE_MISS, "deadline_miss"),
    (alarm::FAIL_SAFE, "fail_safe"),
];

/// The controller's state as a `diagnostic_msgs/DiagnosticStatus`: level
/// ERROR on a fail-safe or an emergency stop, WARN on any other alarm or a
/// fading link, else OK; one value per status bit and alarm
/// (`"true"`/`"false"`), the raw bits in hexadecimal and the servo cycle.
pub fn status_report(
    name: &str,
    hardware_id: &str,
    status_bits: u32,
    alarm_bits: u32,
    cycle: u32,
) -> DiagnosticStatus {
    let level = if alarm_bits & alarm::FAIL_SAFE != 0 || status_bits & status::EMERGENCY_STOP != 0 {
        DiagnosticStatus::ERROR
    } else if alarm_bits != 0 || status_bits & status::LINK_FADING != 0 {
        DiagnosticStatus::WARN
    } else {
        DiagnosticStatus::OK
    };
    let mut raised: Vec<&str> = ALARM_NAMES
        .iter()
        .filter(|(b, _)| alarm_bits & b != 0)
        .map(|(_, n)| *n)
        .collect();
    if status_bits & status::EMERGENCY_STOP != 0 {
        raised.insert(0, "emergency_stop");
    }
    let message = match (raised.is_empty(), status_bits & status::POWER_ON != 0) {
        (true, true) => "powered".to_owned(),
        (true, false) => "unpowered".to_owned(),
        (false, _) => raised.join(", "),
    };
    let flag = |v: bool| if v { "true" } else { "false" }.to_owned();
    let mut values: Vec<KeyValue> = STATUS_NAMES
        .iter()
        .map(|(b, n)| KeyValue {
            key: (*n).to_owned(),
            value: flag(status_bits & b != 0),
        })
        .collect();
    values.extend(ALARM_NAMES.iter().map(|(b, n)| KeyValue {
        key: (*n).to_owned(),
        value: flag(alarm_bits & b != 0),
    }));
    values.push(KeyValue {
        key: "status_bits".into(),
        value: format!("{status_bits:#x}"),
    });
    values.push(KeyValue {
        key: "alarm_bits".into(),
        value: format!("{alarm_bits:#x}"),
    });
    values.push(KeyValue {
        key: "cycle".into(),
        value: cycle.to_string(),
    });
    DiagnosticStatus {
        level,
        name: name.to_owned(),
        message,
        hardware_id: hardware_id.to_owned(),
        values,
    }
}

/// No answer from the controller for this long: the status turns STALE.
pub const STALE_AFTER: std::time::Duration = std::time::Duration::from_secs(1);

/// The status when the controller has not answered for `silent`: level
/// STALE, no values (the last answer's state is no longer known).
pub fn stale_report(
    name: &str,
    hardware_id: &str,
    silent: std::time::Duration,
) -> DiagnosticStatus {
    DiagnosticStatus {
        level: DiagnosticStatus::STALE,
        name: name.to_owned(),
        message: format!(
            "no answer from the controller for {:.1} s",
            silent.as_secs_f64()
        ),
        hardware_id: hardware_id.to_owned(),
        values: Vec::new(),
    }
}

/// The status that says the controller ended the session (`e`, with its
/// VirtuoseAPI code `code`): level ERROR; the node stops after it.
pub fn ended_report(
    name: &str,
    hardware_id: &str,
    e: &virtuose_api::VirtError,
    code: i32,
) -> DiagnosticStatus {
    DiagnosticStatus {
        level: DiagnosticStatus::ERROR,
        name: name.to_owned(),
        message: format!("{e} (VirtuoseAPI error {code})"),
        hardware_id: hardware_id.to_owned(),
        values: Vec::new(),
    }
}

/// The coupling set-point (virtual-object pose streamed to the controller)
/// for the subscribed `target` pose (if any) plus the added `wrench` (if
/// any): the target itself; with a wrench, offset by the spring
/// (`k_lin` N/m, `k_rot` N·m/rad) so that the coupling adds that wrench on
/// the handle (`virtuose_api::kin::force_setpoint`), from the target, or
/// from the handle when there is no target. `None` when neither is given.
pub fn setpoint(
    frames: &Frames,
    handle: &[f32; 7],
    target: Option<&[f32; 7]>,
    wrench: Option<&[f32; 6]>,
    k_lin: f64,
    k_rot: f64,
) -> Option<[f32; 7]> {
    match (target, wrench) {
        (None, None) => None,
        (Some(t), None) => Some(*t),
        (t, Some(w)) => Some(kin::force_setpoint(
            frames,
            t.unwrap_or(handle),
            w,
            k_lin,
            k_rot,
        )),
    }
}

/// Names of the arm's joints: `PREFIXjoint1` … `PREFIXjoint6`.
pub fn joint_names(prefix: &str) -> Vec<String> {
    (1..=kin::NB_AXES)
        .map(|i| format!("{prefix}joint{i}"))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buttons_follow_the_status_bits() {
        assert_eq!(buttons(0), vec![0, 0]);
        assert_eq!(buttons(status::BUTTON_1), vec![1, 0]);
        assert_eq!(buttons(status::BUTTON_2 | status::POWER_ON), vec![0, 1]);
    }

    fn value<'a>(d: &'a DiagnosticStatus, key: &str) -> &'a str {
        &d.values
            .iter()
            .find(|kv| kv.key == key)
            .unwrap_or_else(|| panic!("no {key}"))
            .value
    }

    #[test]
    fn status_levels() {
        let ok = status_report("n", "h", status::POWER_ON | status::DEAD_MAN, 0, 5);
        assert_eq!(ok.level, DiagnosticStatus::OK);
        assert_eq!(ok.message, "powered");
        assert_eq!(value(&ok, "power_on"), "true");
        assert_eq!(value(&ok, "dead_man"), "true");
        assert_eq!(value(&ok, "fail_safe"), "false");
        assert_eq!(value(&ok, "cycle"), "5");
        assert_eq!(value(&ok, "status_bits"), "0x5");

        let warn = status_report("n", "h", 0, alarm::JOINT_LIMIT, 1);
        assert_eq!(warn.level, DiagnosticStatus::WARN);
        assert_eq!(warn.message, "joint_limit");

        let err = status_report("n", "h", 0, alarm::FAIL_SAFE | alarm::DEADLINE_MISS, 1);
        assert_eq!(err.level, DiagnosticStatus::ERROR);
        assert_eq!(err.message, "deadline_miss, fail_safe");
        assert_eq!(value(&err, "fail_safe"), "true");

        let estop = status_report("n", "h", status::EMERGENCY_STOP, 0, 1);
        assert_eq!(estop.level, DiagnosticStatus::ERROR);
        assert_eq!(estop.message, "emergency_stop");
    }

    #[test]
    fn stale_status() {
        let d = stale_report("n", "h", std::time::Duration::from_millis(1500));
        assert_eq!(d.level, DiagnosticStatus::STALE);
        assert_eq!(d.message, "no answer from the controller for 1.5 s");
        assert!(d.values.is_empty());
    }

    #[test]
    fn setpoint_sources() {
        let f = Frames::default();
        let handle = [0.4, 0.0, 0.2, 0.0, 0.0, 0.0, 1.0];
        let target = [0.5, 0.1, 0.2, 0.0, 0.0, 0.0, 1.0];
        assert_eq!(setpoint(&f, &handle, None, None, 200.0, 1.0), None);
        assert_eq!(
            setpoint(&f, &handle, Some(&target), None, 200.0, 1.0),
            Some(target)
        );
        // 2 N along x on a 200 N/m spring: 1 cm from the handle.
        let w = [2.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let from_handle = setpoint(&f, &handle, None, Some(&w), 200.0, 1.0).expect("set-point");
        assert!((from_handle[0] - 0.41).abs() < 1e-6, "{from_handle:?}");
        let from_target =
            setpoint(&f, &handle, Some(&target), Some(&w), 200.0, 1.0).expect("set-point");
        assert!((from_target[0] - 0.51).abs() < 1e-6, "{from_target:?}");
        assert_eq!(from_target[1], 0.1);
    }

    #[test]
    fn joint_names_carry_the_prefix() {
        assert_eq!(
            joint_names("left_"),
            vec![
                "left_joint1",
                "left_joint2",
                "left_joint3",
                "left_joint4",
                "left_joint5",
                "left_joint6"
            ]
        );
    }
}
