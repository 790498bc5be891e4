#!/usr/bin/env python3
"""Feel a MuJoCo scene through the arm: a table, three rigid objects and a
tool, the object the user holds (VirtMech: MuJoCo simulates the tool,
hapticctrl couples the handle to it).

Every period (1 ms) the coupling wrench the controller computed between the
handle and the tool is applied to the tool, MuJoCo steps, and the tool's
pose and twist are streamed back: what MuJoCo's contacts, collisions and
friction do to the tool, the handle feels. The tool carries no weight
(gravcomp) so that only contacts are felt.

    mujoco_table.py --address HOST#5000?key=hap.key [--duration S] [--out DIR]
                    [--headless | --viewer] [--origin auto|X,Y,Z] [--clock host|controller]

Headless unless a display exists (then MuJoCo's passive viewer; --headless
forces it off). At the end the trajectory, the contact forces and the
coupling force are plotted to DIR/mujoco_table.png (matplotlib, Agg) and
the samples saved to DIR/mujoco_table.npz.

Frames: MuJoCo's world frame is the controller's world frame shifted by
`origin` (controller = MuJoCo + origin); `--origin auto` puts the tool where
the handle is at the start. Positions in m, forces in N.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

import hapticctrl as hc

SCENE = """
<mujoco model="hapticctrl table">
  <option timestep="{dt}" gravity="0 0 -9.81"/>
  <visual><global offwidth="640" offheight="480"/></visual>
  <worldbody>
    <light pos="0 -0.5 1.5" dir="0 0.3 -1"/>
    <geom name="floor" type="plane" size="1.5 1.5 0.1" pos="0 0 -0.75" rgba="0.8 0.8 0.8 1"/>
    <body name="table" pos="0 0 -0.025">
      <geom name="table_top" type="box" size="0.4 0.3 0.025" friction="0.8 0.005 0.0001" rgba="0.6 0.4 0.2 1"/>
      <geom type="box" size="0.02 0.02 0.35" pos="0.37 0.27 -0.375"/>
      <geom type="box" size="0.02 0.02 0.35" pos="-0.37 0.27 -0.375"/>
      <geom type="box" size="0.02 0.02 0.35" pos="0.37 -0.27 -0.375"/>
      <geom type="box" size="0.02 0.02 0.35" pos="-0.37 -0.27 -0.375"/>
    </body>
    <body name="cube" pos="0.15 0.08 0.03">
      <freejoint/>
      <geom name="cube" type="box" size="0.03 0.03 0.03" mass="0.2" rgba="0.2 0.4 0.8 1"/>
    </body>
    <body name="ball" pos="-0.12 0.1 0.04">
      <freejoint/>
      <geom name="ball" type="sphere" size="0.04" mass="0.1" rgba="0.8 0.2 0.2 1"/>
    </body>
    <body name="can" pos="0.05 -0.15 0.05">
      <freejoint/>
      <geom name="can" type="cylinder" size="0.03 0.05" mass="0.15" rgba="0.2 0.7 0.3 1"/>
    </body>
    <body name="tool" pos="{tool_x} {tool_y} {tool_z}" gravcomp="1">
      <freejoint/>
      <geom name="tool_tip" type="sphere" size="0.02" mass="0.2" rgba="0.9 0.9 0.1 1"/>
      <geom name="tool_shaft" type="capsule" fromto="0 0 0.02 0 0 0.12" size="0.008" mass="0.05" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
</mujoco>
"""

TOOL_START = (0.0, 0.0, 0.05)


@dataclass
class Trace:
    """One sample per cycle (MuJoCo frame)."""

    t: list[float] = field(default_factory=list)
    handle: list[np.ndarray] = field(default_factory=list)
    tool: list[np.ndarray] = field(default_factory=list)
    contact_table: list[float] = field(default_factory=list)
    contact_objects: list[float] = field(default_factory=list)
    coupling: list[np.ndarray] = field(default_factory=list)
    raw_coupling: list[np.ndarray] = field(default_factory=list)
    fade: list[float] = field(default_factory=list)
    link_ok: list[bool] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v, dtype=np.float64) for k, v in self.__dict__.items()}


class Scene:
    """The MuJoCo model, its data and the contact bookkeeping."""

    def __init__(self, dt: float):
        import mujoco

        self.mj = mujoco
        xml = SCENE.format(dt=dt, tool_x=TOOL_START[0], tool_y=TOOL_START[1], tool_z=TOOL_START[2])
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.tool = self.model.body("tool").id
        self.tool_geoms = {self.model.geom("tool_tip").id, self.model.geom("tool_shaft").id}
        self.table = self.model.body("table").id
        self._f6 = np.zeros(6)
        self._v6 = np.zeros(6)
        mujoco.mj_forward(self.model, self.data)

    def step(self, wrench: np.ndarray) -> None:
        self.data.xfrc_applied[self.tool, :] = wrench
        self.mj.mj_step(self.model, self.data)

    def contact_normals(self) -> tuple[float, float]:
        """Normal force on the tool from the table, and from the objects, N."""
        table = objects = 0.0
        d, m = self.data, self.model
        for i in range(d.ncon):
            c = d.contact[i]
            g1, g2 = int(c.geom1), int(c.geom2)
            if g1 in self.tool_geoms:
                other = g2
            elif g2 in self.tool_geoms:
                other = g1
            else:
                continue
            self.mj.mj_contactForce(m, d, i, self._f6)
            if m.geom_bodyid[other] == self.table:
                table += self._f6[0]
            else:
                objects += self._f6[0]
        return table, objects

    def tool_pose_twist(self) -> tuple[np.ndarray, np.ndarray]:
        """Pose [x,y,z,qx,qy,qz,qw] and twist [v, w] of the tool, world frame."""
        p = self.data.xpos[self.tool]
        w, x, y, z = self.data.xquat[self.tool]
        self.mj.mj_objectVelocity(self.model, self.data, self.mj.mjtObj.mjOBJ_BODY, self.tool, self._v6, 0)
        twist = np.concatenate([self._v6[3:], self._v6[:3]])
        return np.array([p[0], p[1], p[2], x, y, z, w]), twist


def run(
    session: hc.Session,
    duration: float,
    *,
    period: float = 0.001,
    origin: np.ndarray | None = None,
    viewer: bool = False,
    on_tick: Callable[[hc.Tick], bool | None] | None = None,
    link_timeout: float = 0.05,
    fade: float = 0.1,
    clock: str = "host",
    power_off: bool = True,
    time_step: float | None = None,
) -> tuple[Trace, hc.LoopStats]:
    """Couple the handle to the tool for `duration` s. `origin`: the
    controller's coordinates of MuJoCo's origin (None: the handle's position
    at the start minus the tool's). `on_tick(tick)`, if given, is called
    first every cycle; returning False ends the run. `clock`: "host" steps
    MuJoCo once per period; "controller" by the servo cycles the answers
    show (none without a new answer, and then nothing is streamed: the
    set-points follow the controller's rate), for a controller slower than
    the host.
    `power_off`: request the arm's power off at the end.
    `time_step`: the integration step declared for the attached object
    (default `period`). VirtMech caps the coupling's stiffness at
    mass/time_step², so a client that holds one force over several MuJoCo
    steps (clock "controller" against a slow emulated guest) declares the
    longest such hold, and the coupling stays stable for it."""
    if clock not in ("host", "controller"):
        raise ValueError(f"clock {clock!r}: host or controller")
    scene = Scene(period)
    session.set_time_step(period if time_step is None else time_step)
    session.set_command_type("virtmech")
    mass = float(scene.model.body_subtreemass[scene.tool])
    inertia = scene.model.body_inertia[scene.tool]
    session.attach_vo(mass, inertia)
    session.set_power_on(True)
    if not session.wait_answer(5.0):
        raise hc.ControllerTimeoutError(6, "no answer from the controller after power-on")
    if origin is None:
        origin = session.get_position()[:3] - np.asarray(TOOL_START)
    origin = np.asarray(origin, dtype=np.float64)
    offset7 = np.concatenate([origin, np.zeros(4)])
    trace = Trace()
    view = None
    if viewer:
        import mujoco.viewer

        view = mujoco.viewer.launch_passive(scene.model, scene.data)

    last_cycle = [session.cycle]

    def tick(t: hc.Tick):
        if on_tick is not None and on_tick(t) is False:
            return False
        if clock == "host":
            steps = 1
        else:
            # Cycles since the last step (wrapping 32-bit counter), bounded.
            steps = min((t.cycle - last_cycle[0]) % (1 << 32), 50)
            last_cycle[0] = t.cycle
        for _ in range(steps):
            scene.step(t.force)
        if clock == "controller" and steps == 0:
            return None  # no new answer: nothing new to send (paced by the controller)
        table, objects = scene.contact_normals()
        pose, twist = scene.tool_pose_twist()
        trace.t.append(t.t)
        trace.handle.append(t.position[:3] - origin)
        trace.tool.append(pose[:3].copy())
        trace.contact_table.append(table)
        trace.contact_objects.append(objects)
        trace.coupling.append(t.force[:3].copy())
        trace.raw_coupling.append(t.raw_force[:3].copy())
        trace.fade.append(t.fade)
        trace.link_ok.append(t.link_ok)
        if view is not None and t.index % 16 == 0:
            if not view.is_running():
                return False
            view.sync()
        return pose + offset7, twist

    try:
        stats = session.run_loop(tick, period=period, duration=duration, link_timeout=link_timeout, fade=fade)
    finally:
        if view is not None:
            view.close()
    if power_off:
        try:
            session.set_power_on(False)
        except hc.VirtuoseError:
            pass  # the link may be gone: the controller fades on its own
    return trace, stats


def plot(trace: Trace, out: Path, title: str = "") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = trace.arrays()
    t = a["t"]
    fig, ax = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    ax[0].plot(t, a["handle"][:, 2], label="handle z")
    ax[0].plot(t, a["tool"][:, 2], label="tool z")
    ax[0].plot(t, a["handle"][:, 0], "--", label="handle x")
    ax[0].plot(t, a["tool"][:, 0], "--", label="tool x")
    ax[0].axhline(0.02, color="k", lw=0.5, ls=":", label="tool on the table")
    ax[0].set_ylabel("position (m, MuJoCo frame)")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].plot(t, a["contact_table"], label="table on the tool (normal)")
    ax[1].plot(t, a["contact_objects"], label="objects on the tool (normal)")
    ax[1].set_ylabel("contact force (N)")
    ax[1].legend(loc="upper right", fontsize=8)
    ax[2].plot(t, -a["coupling"][:, 2], label="felt at the handle, z (= -coupling on the tool)")
    ax[2].plot(t, -a["raw_coupling"][:, 2], ":", label="controller's last wrench, z (not faded)")
    ax[2].plot(t, np.linalg.norm(a["coupling"], axis=1), "--", label="|coupling force|")
    lost = a["link_ok"] < 0.5
    if lost.any():
        for a_ in ax:
            a_.fill_between(t, 0, 1, where=lost, transform=a_.get_xaxis_transform(), color="red", alpha=0.1, label=None)
    ax[2].set_ylabel("coupling force (N)")
    ax[2].set_xlabel("time (s, host clock); red: link lost")
    ax[2].legend(loc="upper right", fontsize=8)
    fig.suptitle(title or "hapticctrl + MuJoCo: the handle coupled to the tool")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    png = out / "mujoco_table.png"
    fig.savefig(png, dpi=90)
    plt.close(fig)
    np.savez(out / "mujoco_table.npz", **a)
    return png


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--address", required=True, help="HOST#PORT, optionally ?key=FILE (or HAP_KEY_FILE)")
    ap.add_argument("--key", help="key file (protocol v2)")
    ap.add_argument("--insecure", action="store_true", help="unauthenticated protocol v1")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--out", type=Path, default=Path("results/mujoco"))
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--headless", action="store_true", help="no viewer even with a display")
    g.add_argument("--viewer", action="store_true", help="MuJoCo's viewer (needs a display)")
    ap.add_argument("--origin", default="auto", help="auto or X,Y,Z: the controller's coordinates of MuJoCo's origin")
    ap.add_argument("--clock", choices=("host", "controller"), default="host",
                    help="step MuJoCo once per period (host) or by the controller's servo cycles")
    args = ap.parse_args(argv)
    origin = None if args.origin == "auto" else np.array([float(v) for v in args.origin.split(",")])
    has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    viewer = args.viewer or (has_display and not args.headless)
    try:
        with hc.Session(args.address, key=args.key, insecure=args.insecure) as s:
            trace, stats = run(s, args.duration, origin=origin, viewer=viewer, clock=args.clock)
    except hc.VirtuoseError as e:
        print(f"mujoco_table: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    png = plot(trace, args.out)
    a = trace.arrays()
    print(f"loop: {stats}")
    print(f"max contact force on the tool: table {a['contact_table'].max():.2f} N, objects {a['contact_objects'].max():.2f} N")
    print(f"max force at the handle: {np.linalg.norm(a['coupling'], axis=1).max():.2f} N")
    print(f"plot: {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
