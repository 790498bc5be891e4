"""hapticctrl: Python client of the hapticctrl haptic controller.

A thin layer over the Rust library ``virtuose_api`` (one protocol
implementation): ``Session`` is VirtuoseAPI's context, a context manager::

    import hapticctrl as hc
    with hc.Session("192.168.7.2#5000?key=hap.key") as s:
        s.set_command_type("virtmech")
        ...

Vectors are numpy float64 arrays: poses ``[x, y, z, qx, qy, qz, qw]`` (m,
unit quaternion), twists ``[vx, vy, vz, wx, wy, wz]`` (m/s, rad/s), wrenches
``[fx, fy, fz, tx, ty, tz]`` (N, N·m), all in the client's world frame (the
base and observation frames set with ``set_base_frame`` /
``set_observation_frame``). ``get_force()`` is the coupling wrench the
controller applies to the virtual object; the handle feels its opposite.
"""

from ._errors import (
    AddressError,
    ClosedError,
    CommunicationError,
    ControllerTimeoutError,
    InvalidArgumentError,
    NoDataError,
    NoKeyError,
    RefusedError,
    SessionEndedError,
    VirtuoseError,
)
from ._native import DEFAULT_PORT, KEY_ENV, VERSION, LoopStats, Session, Tick, error_message
from ._native import (  # hap_core::vp::status bits of Session.status and Tick.status
    STATUS_COUPLED,
    STATUS_DEAD_MAN,
    STATUS_EMERGENCY_STOP,
    STATUS_LINK_FADING,
    STATUS_MOTORS_ENABLED,
    STATUS_POWER_ON,
)


__version__ = VERSION
__all__ = [
    "AddressError",
    "ClosedError",
    "CommunicationError",
    "ControllerTimeoutError",
    "DEFAULT_PORT",
    "InvalidArgumentError",
    "KEY_ENV",
    "LoopStats",
    "NoDataError",
    "NoKeyError",
    "RefusedError",
    "Session",
    "SessionEndedError",
    "Tick",
    "VirtuoseError",
    "error_message",
]
