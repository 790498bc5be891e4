"""The periodic callback loop: its count and deadlines, the GIL released
while it waits, set-points streamed from the callback, the wrench's fade
when the link is lost."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import hapticctrl as hc
from conftest import num


def powered(fake, key_file) -> hc.Session:
    s = hc.Session(fake.address, key=key_file)
    s.set_command_type("virtmech")
    s.attach_vo(0.5, [1e-3] * 3)
    s.set_power_on(True)
    assert s.wait_answer(2.0)
    return s


def test_cycles_deadlines_and_streaming(fake, key_file):
    period = 0.001
    ticks = []

    def cb(t: hc.Tick):
        ticks.append((t.index, t.t, t.position.copy()))
        for v, n in ((t.position, 7), (t.speed, 6), (t.force, 6), (t.raw_force, 6)):
            assert v.shape == (n,) and v.dtype == np.float64
        return t.position, np.zeros(6)

    with powered(fake, key_file) as s:
        st = s.run_loop(cb, period=period, cycles=300, record=True)
        assert st.cycles == 300
        assert [i for i, _, _ in ticks] == list(range(300))
        # Deadlines are absolute: the i-th call is never before i periods.
        for i, t, _ in ticks:
            assert t >= i * period - 1e-6
        assert all(b[1] > a[1] for a, b in zip(ticks, ticks[1:]))
        assert st.periods_us.shape == (299,) and st.periods_us.dtype == np.float32
        assert st.work_us.shape == (299,)
        assert abs(float(np.mean(st.periods_us.astype(np.float64))) - st.period_mean_us) < 1e-2 * st.period_mean_us
        assert st.rate_hz == pytest.approx(1e6 / st.period_mean_us)
        assert st.period_min_us <= st.period_mean_us <= st.period_max_us
        print(f"\nloop at 1 kHz (host, fake controller): {st}")
        assert s.wait_answer(1.0)
    assert num(fake.stats(), "frames.vpr_stream") == 300


def test_duration_and_stop(fake, key_file):
    with powered(fake, key_file) as s:
        st = s.run_loop(lambda t: None, period=0.01, duration=0.2)
        # Deadlines at 0, 10, ..., 190 ms: at most 20 calls.
        assert 1 <= st.cycles <= 20
        st = s.run_loop(lambda t: False if t.index == 4 else None, cycles=100)
        assert st.cycles == 5
    assert num(fake.stats(), "frames.vpr_stream") == 0


def test_an_exception_in_the_callback_ends_the_loop(fake, key_file):
    calls = []

    def cb(t):
        calls.append(t.index)
        if t.index == 3:
            raise KeyError("from the callback")

    with powered(fake, key_file) as s:
        with pytest.raises(KeyError):
            s.run_loop(cb, cycles=100)
        assert calls == [0, 1, 2, 3]
        # The session is usable again, and a loop can run again.
        assert s.run_loop(lambda t: None, cycles=3).cycles == 3
        with pytest.raises(RuntimeError):
            s.run_loop(lambda t: s.close(), cycles=1)


def test_the_gil_is_released_between_calls(fake, key_file):
    # A thread woken by the first call can only run before the second call
    # if the loop does not hold the GIL while it waits (200 ms here).
    go = threading.Event()
    order: list[str] = []

    def other():
        go.wait()
        order.append("thread")

    th = threading.Thread(target=other)
    th.start()

    def cb(t):
        order.append(f"call {t.index}")
        if t.index == 0:
            go.set()

    with powered(fake, key_file) as s:
        s.run_loop(cb, period=0.2, cycles=2)
    th.join(5)
    assert order == ["call 0", "thread", "call 1"]


def test_the_wrench_fades_when_the_link_is_lost(fake, key_file):
    log = []
    offset = np.array([0.0, 0.0, 0.01, 0, 0, 0, 0])

    def cb(t: hc.Tick):
        if t.index == 50:
            fake.cut()
        if t.index == 300:
            fake.restore()
        log.append((t.index, t.link_ok, t.fade, t.force.copy(), t.raw_force.copy(), t.answer_age))
        return t.position + offset, np.zeros(6)

    with powered(fake, key_file) as s:
        st = s.run_loop(cb, cycles=600, link_timeout=0.05, fade=0.1)
    idx = np.array([r[0] for r in log])
    ok = np.array([r[1] for r in log])
    fade = np.array([r[2] for r in log])
    force = np.array([r[3] for r in log])
    raw = np.array([r[4] for r in log])
    # Before the cut: full force (the 1 cm offset on a 300 N/m spring).
    assert ok[:50].all() and (fade[:50] == 1.0).all()
    assert np.all(np.abs(force[10:50, 2]) > 2.0)
    # While cut: the link is declared lost, the wrench given falls to 0
    # (monotonically), while the stale raw wrench stays.
    lost = ~ok & (idx < 300)
    assert lost.any() and st.link_lost_cycles >= lost.sum()
    cut_part = (idx >= 50) & (idx < 300)
    assert np.all(np.diff(fade[cut_part]) <= 1e-12)
    zero = cut_part & (fade == 0.0)
    assert zero.any()
    assert np.all(force[zero] == 0.0)
    assert np.all(np.abs(raw[zero, 2]) > 2.0)
    np.testing.assert_allclose(force, raw * fade[:, None], atol=1e-6)
    # Restored: the link comes back and the wrench rises back, no step.
    after = idx >= 300
    assert ok[after].any()
    assert fade[-1] == 1.0
    assert np.all(np.diff(fade[after]) >= -1e-12)
