"""Type stubs of hapticctrl's native module (virtuose_api through PyO3)."""

from collections.abc import Callable
from os import PathLike
from typing import Literal

import numpy as np
import numpy.typing as npt

KEY_ENV: str
DEFAULT_PORT: int
VERSION: str
STATUS_POWER_ON: int
STATUS_MOTORS_ENABLED: int
STATUS_DEAD_MAN: int
STATUS_EMERGENCY_STOP: int
STATUS_COUPLED: int
STATUS_LINK_FADING: int

Vector = npt.NDArray[np.float64]
VectorLike = npt.ArrayLike
CommandType = Literal["none", "impedance", "virtmech"]
IndexingMode = Literal[
    "all", "trans", "none", "all_force_feedback_inhibition", "trans_force_feedback_inhibition"
]

def error_message(code: int) -> str:
    """VirtuoseAPI's generic message of an error code."""

class Tick:
    """One cycle of Session.run_loop."""

    index: int
    t: float
    dt: float
    position: Vector  # (7,) handle pose [x, y, z, qx, qy, qz, qw], m
    speed: Vector  # (6,) handle twist [vx, vy, vz, wx, wy, wz], m/s, rad/s
    force: Vector  # (6,) coupling wrench on the virtual object, N, N·m, times fade
    raw_force: Vector  # (6,) the wrench as received
    fade: float
    link_ok: bool
    answer_age: float
    cycle: int
    status: int

class LoopStats:
    cycles: int
    overruns: int
    rate_hz: float
    period_mean_us: float
    period_std_us: float
    period_min_us: float
    period_max_us: float
    lateness_mean_us: float
    lateness_max_us: float
    work_mean_us: float
    work_max_us: float
    link_lost_cycles: int
    periods_us: npt.NDArray[np.float32] | None
    work_us: npt.NDArray[np.float32] | None

LoopResult = tuple[VectorLike, VectorLike] | Literal[False] | None

class Session:
    """A session with a hapticctrl controller; a context manager."""

    def __init__(
        self,
        address: str,
        *,
        key: str | PathLike[str] | None = None,
        insecure: bool = False,
        reply_timeout: float = 0.25,
        attempts: int = 4,
        link_passivity: bool = False,
    ) -> None: ...
    def __enter__(self) -> Session: ...
    def __exit__(self, *exc: object) -> bool: ...
    def close(self) -> None: ...
    @property
    def closed(self) -> bool: ...
    @property
    def authenticated(self) -> bool: ...
    @property
    def session_id(self) -> int: ...
    @property
    def period_us(self) -> int: ...
    @property
    def address(self) -> str: ...
    def set_time_step(self, dt: float) -> None: ...
    def set_command_type(self, command: CommandType) -> None: ...
    def set_indexing_mode(self, mode: IndexingMode) -> None: ...
    def set_force_factor(self, k: float) -> None: ...
    def set_speed_factor(self, k: float) -> None: ...
    def set_base_frame(self, pose: VectorLike) -> None: ...
    def set_observation_frame(self, pose: VectorLike) -> None: ...
    def attach_vo(self, mass: float, inertia: VectorLike) -> None: ...
    def detach_vo(self) -> None: ...
    def set_power_on(self, on: bool) -> None: ...
    def set_speed(self, twist: VectorLike) -> None: ...
    def set_position(self, pose: VectorLike) -> None: ...
    def get_position(self) -> Vector: ...
    def get_speed(self) -> Vector: ...
    def get_force(self) -> Vector: ...
    @property
    def status(self) -> int: ...
    @property
    def power_on(self) -> bool: ...
    @property
    def dead_man(self) -> bool: ...
    @property
    def emergency_stop(self) -> bool: ...
    @property
    def alarms(self) -> int: ...
    @property
    def cycle(self) -> int: ...
    def wait_answer(self, timeout: float = 1.0) -> bool: ...
    def link_stats(self) -> dict[str, float]: ...
    def run_loop(
        self,
        callback: Callable[[Tick], LoopResult],
        *,
        period: float = 0.001,
        duration: float | None = None,
        cycles: int | None = None,
        link_timeout: float = 0.05,
        fade: float = 0.1,
        record: bool = False,
    ) -> LoopStats: ...
