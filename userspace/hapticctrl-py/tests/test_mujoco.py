"""The MuJoCo example, headless, against the fake controller: the handle's
scripted push into the table yields the table's contact force at the handle
(the coupling force equals the contact force while the tool rests on the
table), nothing while the tool is in the air, and the force fades when the
link is lost."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import hapticctrl as hc

mujoco = pytest.importorskip("mujoco")

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "mujoco_table.py"


def example():
    spec = importlib.util.spec_from_file_location("mujoco_table", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["mujoco_table"] = mod
    spec.loader.exec_module(mod)
    return mod


def test_a_push_into_the_table_is_felt_and_fades_with_the_link(start_fake, key_file, tmp_path):
    # The handle goes up and down 6 cm around where the tool starts (5 cm
    # above the table, its tip 3 cm above): 3 cm into the table at
    # t = 1.5 s and 3.5 s (the fake's clock: one period per answer).
    fake = start_fake("--center", "0,0,0", "--amplitude", "0,0,0.06", "--freq", "0.5")
    ex = example()
    # The fake's clock is its answer count: on a loaded host it runs behind
    # the host's, so the cut is placed by the handle's position (the second
    # push, the handle 1 cm below the tool's resting height), not by time.
    cut = {}

    def on_tick(t: hc.Tick):
        z = t.position[2]
        if "at" not in cut:
            if t.t > 0.1 and z > 0.05:
                cut["rose"] = cut.get("rose", 0) + (1 if cut.get("phase") != "up" else 0)
                cut["phase"] = "up"
            elif z < -0.04:
                cut["phase"] = "down"
            if cut.get("rose") == 2 and z < -0.04:
                fake.cut()
                cut["at"] = t.t
        elif t.t > cut["at"] + 0.6:
            return False
        return None

    with hc.Session(fake.address, key=key_file) as s:
        trace, stats = ex.run(s, 15.0, on_tick=on_tick, link_timeout=0.05, fade=0.1)
    assert "at" in cut, "the second push never came"
    cut_at = cut["at"]
    png = ex.plot(trace, tmp_path)
    assert png.exists() and png.stat().st_size > 10_000
    a = trace.arrays()
    t, hz = a["t"], a["handle"][:, 2]
    table, coupling_z = a["contact_table"], a["coupling"][:, 2]
    felt_z = -coupling_z  # the handle feels the opposite of the force on the tool
    print(f"\n{stats}\nmax table contact {table.max():.2f} N, max felt {felt_z.max():.2f} N")

    first = t < cut_at
    # In the air (handle above the tool's resting height): no contact.
    air = first & (t > 0.2) & (hz > 0.05)
    assert air.sum() > 100
    assert np.all(table[air] == 0.0)

    # The first push: the handle 1 cm below the table, the tool on it.
    push = first & (hz < 0.0)
    assert push.sum() > 100
    assert table[push].max() > 6.0
    # What the handle feels is the table's contact force (quasi-static).
    err = np.abs(felt_z[push] - table[push])
    assert np.median(err) < 0.05 * table[push].max() + 0.2, (np.median(err), table[push].max())
    assert felt_z[push].min() > 3.0
    # The tool stays on the table while the handle goes into it.
    assert np.all(a["tool"][push, 2] > 0.015)

    # The link is cut during the second push: the force given to
    # the tool fades to nothing (link_timeout 50 ms + fade 100 ms), the
    # contact force with it, while the controller's last (stale) wrench
    # stays large.
    before = (t > cut_at - 0.05) & (t < cut_at)
    assert table[before].max() > 2.0
    after = t > cut_at + 0.05 + 0.1 + 0.05
    assert after.sum() > 100
    assert np.all(a["fade"][after] == 0.0)
    assert np.all(coupling_z[after] == 0.0)
    assert np.all(table[after] < 0.2)
    assert np.all(-a["raw_coupling"][after, 2] > 3.0)
    lost = ~a["link_ok"].astype(bool)
    assert lost.any() and t[lost].min() > cut_at
