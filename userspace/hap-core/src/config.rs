//! Servo configuration: the read-mostly parameters a client sets through the
//! protocol (PROTO_IN writes them under the configuration rwsem, SERVO reads
//! them each cycle). Names follow Haption's VirtuoseAPI where one applies.

use super::fixed::{Fx, Pose, Vec3};

/// How the arm is commanded (VirtuoseAPI `VirtCommandType`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(u32)]
pub enum CommandType {
    /// No coupling: the arm is free (gravity compensated when powered).
    #[default]
    None = 0,
    /// Cartesian impedance: the client streams a pose/twist (VPr), the
    /// controller couples the handle to it with a spring-damper and returns
    /// the coupling wrench (`COMMAND_TYPE_IMPEDANCE`).
    Impedance = 1,
    /// Virtual mechanism: like `Impedance` but the coupling is computed on a
    /// virtual object of known mass attached by the client (`COMMAND_TYPE_VIRTMECH`).
    VirtMech = 2,
}

impl CommandType {
    /// Decode the wire value; `None` for an unknown value.
    pub const fn from_u32(v: u32) -> Option<CommandType> {
        match v {
            0 => Some(CommandType::None),
            1 => Some(CommandType::Impedance),
            2 => Some(CommandType::VirtMech),
            _ => None,
        }
    }
}

/// What the handle's displacement moves while the user holds the
/// indexing button (VirtuoseAPI `VirtIndexingType`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(u32)]
pub enum IndexingMode {
    /// Translations and rotations are indexed (`INDEXING_ALL`).
    #[default]
    All = 0,
    /// Only translations are indexed (`INDEXING_TRANS`).
    Trans = 1,
    /// No indexing (`INDEXING_NONE`).
    None = 2,
    /// As `All`, force feedback inhibited while indexing
    /// (`INDEXING_ALL_FORCE_FEEDBACK_INHIBITION`).
    AllForceFeedbackInhibition = 3,
    /// As `Trans`, force feedback inhibited while indexing
    /// (`INDEXING_TRANS_FORCE_FEEDBACK_INHIBITION`).
    TransForceFeedbackInhibition = 4,
}

impl IndexingMode {
    /// Decode the wire value; `None` for an unknown value.
    pub const fn from_u32(v: u32) -> Option<IndexingMode> {
        match v {
            0 => Some(IndexingMode::All),
            1 => Some(IndexingMode::Trans),
            2 => Some(IndexingMode::None),
            3 => Some(IndexingMode::AllForceFeedbackInhibition),
            4 => Some(IndexingMode::TransForceFeedbackInhibition),
            _ => None,
        }
    }
}

/// The virtual object a client attached (VIRTMECH): mass and diagonal inertia.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VirtualObjectParams {
    /// kg
    pub mass: Fx,
    /// kg·m², principal moments
    pub inertia: Vec3,
}

/// Everything the client configures. Defaults are a safe, uncoupled arm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ServoConfig {
    /// Base frame: world → arm base (VirtuoseAPI `virtSetBaseFrame`).
    pub base_frame: Pose,
    /// Observation frame: world → observer (`virtSetObservationFrame`).
    pub observation_frame: Pose,
    /// Scale from arm forces to client forces (`virtSetForceFactor`), > 0.
    pub force_factor: Fx,
    /// Scale from arm displacements to client displacements (`virtSetSpeedFactor`), > 0.
    pub speed_factor: Fx,
    /// The client's simulation time step, s (`virtSetTimeStep`).
    pub time_step: Fx,
    pub command_type: CommandType,
    pub indexing_mode: IndexingMode,
    /// `Some` while a virtual object is attached (`virtAttachVO`).
    pub attached_object: Option<VirtualObjectParams>,
}

impl Default for ServoConfig {
    fn default() -> Self {
        ServoConfig {
            base_frame: Pose::default(),
            observation_frame: Pose::default(),
            force_factor: Fx::ONE,
            speed_factor: Fx::ONE,
            time_step: Fx::from_ratio(1, 1000),
            command_type: CommandType::None,
            indexing_mode: IndexingMode::All,
            attached_object: None,
        }
    }
}
