"""Host side of tests/python/run.sh --target qemu: the MuJoCo example
against the module in the guest. MuJoCo follows the controller's clock
(the emulated guest is slower than the host); the scripted user
(tests/data/press.eff) lifts the handle, then presses it down from 2.5 s of
servo time. The handle starts at the bottom of the arm's range: MuJoCo's
origin is put there (the table top 2 cm above it, the tool's resting height
with its 2 cm tip), so the coupled tool rests on the table, leaves it when
the handle is lifted and meets it again when it is pressed. At servo cycle END the client stops streaming
with the session open (the link is lost: the module's watchdog fades the
coupling), waits SILENCE host seconds, powers off and closes. Prints the
figures as `key: value` lines and writes the plot and the samples to OUT.

    python qemu_press.py ADDRESS END_CYCLE SILENCE_S OUT
"""

from __future__ import annotations

import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

import hapticctrl as hc

EXAMPLE = Path(__file__).resolve().parents[2] / "userspace" / "hapticctrl-py" / "examples" / "mujoco_table.py"


def main() -> int:
    address, end_cycle, silence, out = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), Path(sys.argv[4])
    spec = importlib.util.spec_from_file_location("mujoco_table", EXAMPLE)
    ex = importlib.util.module_from_spec(spec)
    sys.modules["mujoco_table"] = ex
    spec.loader.exec_module(ex)
    start = {}

    def on_tick(t: hc.Tick):
        start.setdefault("cycle", t.cycle)
        return False if t.cycle >= end_cycle else None

    # Generous: the reply timeout covers a slow emulated guest.
    with hc.Session(address, reply_timeout=1.0, attempts=4) as s:
        print(f"authenticated: {int(s.authenticated)}")
        # Host-time link timeout and fade long enough for an emulated guest's
        # pauses (it answers ~100 times per host second).
        if not s.wait_answer(5.0):
            raise hc.ControllerTimeoutError(6, "no answer from the controller")
        origin = s.get_position()[:3]
        trace, stats = ex.run(
            s,
            600.0,
            origin=origin,
            on_tick=on_tick,
            clock="controller",
            # The emulated guest answers in bursts: one force is held over
            # up to tens of servo cycles, so the object's integration step
            # declared to VirtMech is 30 ms (its stiffness cap m/ts²).
            time_step=0.03,
            power_off=False,
            link_timeout=0.5,
            fade=0.5,
        )
        last = s.cycle
        time.sleep(silence)  # nothing sent: the module's watchdog fades the coupling
        s.wait_answer(2.0)
        print(f"cycles_during_silence: {s.cycle - last}")
        s.set_power_on(False)
    png = ex.plot(trace, out, "hapticctrl + MuJoCo against the module in QEMU (tcg-icount)")
    a = trace.arrays()
    table, felt = a["contact_table"], -a["coupling"][:, 2]
    press = (a["link_ok"] > 0.5) & (table > 0.5)
    err = np.abs(felt[press] - table[press]) if press.any() else np.array([np.inf])
    print(f"first_cycle: {start.get('cycle', -1)}")
    print(f"loop_cycles: {stats.cycles}")
    print(f"loop_rate_hz: {stats.rate_hz:.1f}")
    print(f"press_samples: {int(press.sum())}")
    print(f"max_table_contact_n: {table.max():.3f}")
    print(f"max_felt_n: {felt.max():.3f}")
    print(f"press_felt_median_n: {np.median(felt[press]) if press.any() else 0:.3f}")
    print(f"press_contact_median_n: {np.median(table[press]) if press.any() else 0:.3f}")
    print(f"press_felt_vs_contact_median_err_n: {np.median(err):.3f}")
    print(f"tool_min_z_m: {a['tool'][:, 2].min():.4f}")
    print(f"tool_max_z_m: {a['tool'][:, 2].max():.4f}")
    lifted = (a["tool"][:, 2] > 0.025) & (table == 0.0)
    print(f"lifted_samples: {int(lifted.sum())}")
    print(f"plot: {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
