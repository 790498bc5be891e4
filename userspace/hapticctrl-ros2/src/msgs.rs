//! ROS 2 Jazzy message layouts used by the node, field for field as in the
//! `.msg` files of `std_msgs`, `geometry_msgs`, `sensor_msgs`,
//! `diagnostic_msgs` and `std_srvs` (CDR: the fields in order, no type
//! information on the wire). DDS peers match a topic by its ROS 2 type name
//! (`geometry_msgs::msg::dds_::PoseStamped_`), which [`type_name`] gives.

use ros2_client::builtin_interfaces::Time;
use ros2_client::{Message, MessageTypeName, ServiceTypeName};
use serde::{Deserialize, Serialize};

/// `std_msgs/Header`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `geometry_msgs/Point`, `geometry_msgs/Vector3` (same layout).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/Quaternion`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

/// `geometry_msgs/Pose`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub position: Vector3,
    pub orientation: Quaternion,
}

/// `geometry_msgs/PoseStamped`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}
impl Message for PoseStamped {}

/// `geometry_msgs/Twist`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}

/// `geometry_msgs/TwistStamped`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TwistStamped {
    pub header: Header,
    pub twist: Twist,
}
impl Message for TwistStamped {}

/// `geometry_msgs/Wrench`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Wrench {
    pub force: Vector3,
    pub torque: Vector3,
}

/// `geometry_msgs/WrenchStamped`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WrenchStamped {
    pub header: Header,
    pub wrench: Wrench,
}
impl Message for WrenchStamped {}

/// `sensor_msgs/JointState`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    pub header: Header,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}
impl Message for JointState {}

/// `sensor_msgs/Joy`: the handle's buttons (1 pressed, 0 released).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Joy {
    pub header: Header,
    pub axes: Vec<f32>,
    pub buttons: Vec<i32>,
}
impl Message for Joy {}

/// `diagnostic_msgs/KeyValue`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

/// `diagnostic_msgs/DiagnosticStatus`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// [`DiagnosticStatus::OK`], `WARN`, `ERROR` or `STALE` (a `byte`).
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}
impl Message for DiagnosticStatus {}

impl DiagnosticStatus {
    pub const OK: u8 = 0;
    pub const WARN: u8 = 1;
    pub const ERROR: u8 = 2;
    pub const STALE: u8 = 3;
}

/// `std_srvs/SetBool` request.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SetBoolRequest {
    pub data: bool,
}
impl Message for SetBoolRequest {}

/// `std_srvs/SetBool` response.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SetBoolResponse {
    pub success: bool,
    pub message: String,
}
impl Message for SetBoolResponse {}

/// The ROS 2 message types the node speaks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MsgType {
    PoseStamped,
    TwistStamped,
    WrenchStamped,
    JointState,
    Joy,
    DiagnosticStatus,
}

impl MsgType {
    /// (package, type) of the `.msg` file.
    pub fn package_and_name(self) -> (&'static str, &'static str) {
        match self {
            MsgType::PoseStamped => ("geometry_msgs", "PoseStamped"),
            MsgType::TwistStamped => ("geometry_msgs", "TwistStamped"),
            MsgType::WrenchStamped => ("geometry_msgs", "WrenchStamped"),
            MsgType::JointState => ("sensor_msgs", "JointState"),
            MsgType::Joy => ("sensor_msgs", "Joy"),
            MsgType::DiagnosticStatus => ("diagnostic_msgs", "DiagnosticStatus"),
        }
    }
}

/// The type name for ros2-client.
pub fn type_name(t: MsgType) -> MessageTypeName {
    let (p, n) = t.package_and_name();
    MessageTypeName::new(p, n)
}

/// `std_srvs/SetBool`.
pub fn set_bool_type() -> ServiceTypeName {
    ServiceTypeName::new("std_srvs", "SetBool")
}

/// A header stamped with the system clock.
pub fn header_now(frame_id: &str) -> Header {
    Header {
        stamp: Time::now(),
        frame_id: frame_id.to_owned(),
    }
}

/// `[x,y,z,qx,qy,qz,qw]` (virtuose_api's layout) → `geometry_msgs/Pose`.
pub fn pose_from_array(p: &[f32; 7]) -> Pose {
    Pose {
        position: Vector3 {
            x: p[0] as f64,
            y: p[1] as f64,
            z: p[2] as f64,
        },
        orientation: Quaternion {
            x: p[3] as f64,
            y: p[4] as f64,
            z: p[5] as f64,
            w: p[6] as f64,
        },
    }
}

/// `geometry_msgs/Pose` → `[x,y,z,qx,qy,qz,qw]`; `None` if a field is not
/// finite or the quaternion is not a rotation (norm far from 1).
pub fn pose_to_array(p: &Pose) -> Option<[f32; 7]> {
    let v = [
        p.position.x,
        p.position.y,
        p.position.z,
        p.orientation.x,
        p.orientation.y,
        p.orientation.z,
        p.orientation.w,
    ];
    if v.iter().any(|x| !x.is_finite()) {
        return None;
    }
    let n = (v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]).sqrt();
    if !(0.9..=1.1).contains(&n) {
        return None;
    }
    let mut out = [0f32; 7];
    for i in 0..3 {
        out[i] = v[i] as f32;
    }
    for i in 3..7 {
        out[i] = (v[i] / n) as f32;
    }
    Some(out)
}

/// `[a,b,c,d,e,f]` → two vectors (twist: linear, angular; wrench: force,
/// torque).
pub fn split6(v: &[f32; 6]) -> (Vector3, Vector3) {
    (
        Vector3 {
            x: v[0] as f64,
            y: v[1] as f64,
            z: v[2] as f64,
        },
        Vector3 {
            x: v[3] as f64,
            y: v[4] as f64,
            z: v[5] as f64,
        },
    )
}

/// Two vectors → `[a,b,c,d,e,f]`; `None` if a field is not finite.
pub fn join6(a: &Vector3, b: &Vector3) -> Option<[f32; 6]> {
    let v = [a.x, a.y, a.z, b.x, b.y, b.z];
    if v.iter().any(|x| !x.is_finite()) {
        return None;
    }
    Some(v.map(|x| x as f32))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_round_trip_and_rejects() {
        let p = [0.4, -0.1, 0.25, 0.0, 0.0, 0.6, 0.8];
        assert_eq!(pose_to_array(&pose_from_array(&p)), Some(p));
        let mut bad = pose_from_array(&p);
        bad.position.y = f64::NAN;
        assert_eq!(pose_to_array(&bad), None);
        let mut zero_q = pose_from_array(&p);
        zero_q.orientation = Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 0.0,
        };
        assert_eq!(pose_to_array(&zero_q), None);
    }

    #[test]
    fn six_vectors_round_trip_and_reject_nan() {
        let v = [1.0, 2.0, 3.0, -4.0, 5.5, 0.25];
        let (a, b) = split6(&v);
        assert_eq!(join6(&a, &b), Some(v));
        let inf = Vector3 {
            x: f64::INFINITY,
            ..a
        };
        assert_eq!(join6(&inf, &b), None);
    }

    /// The CDR bytes of a PoseStamped as ROS 2 lays them out: header (stamp
    /// sec i32, nanosec u32, frame_id string with its NUL), then seven f64
    /// aligned on 8 bytes (from the start of the payload).
    #[test]
    fn pose_stamped_cdr_layout() {
        let m = PoseStamped {
            header: Header {
                stamp: Time::new(7, 9),
                frame_id: "base".into(),
            },
            pose: pose_from_array(&[1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]),
        };
        let b = cdr_encoding::to_vec::<_, byteorder::LittleEndian>(&m).expect("encodes");
        assert_eq!(&b[0..4], &7i32.to_le_bytes());
        assert_eq!(&b[4..8], &9u32.to_le_bytes());
        assert_eq!(&b[8..12], &5u32.to_le_bytes());
        assert_eq!(&b[12..17], b"base\0");
        // 17 bytes, padded to 24 for the first f64.
        assert_eq!(b.len(), 24 + 7 * 8);
        assert_eq!(&b[24..32], &1.0f64.to_le_bytes());
        assert_eq!(&b[72..80], &1.0f64.to_le_bytes());
    }
}
