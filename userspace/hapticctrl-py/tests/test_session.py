"""The Python package against the fake controller behind the bridge's
authentication gate: the session's life cycle, configuration reaching the
controller, numpy shapes and dtypes, keys."""

from __future__ import annotations

import time

import numpy as np
import pytest

import hapticctrl as hc
from conftest import num


def test_context_manager_opens_and_closes(fake, key_file):
    with hc.Session(fake.address, key=key_file) as s:
        assert s.authenticated
        assert s.session_id != 0
        assert s.period_us == 1000
        assert not s.closed
        assert num(fake.stats(), "session_open") == 1
    assert s.closed
    st = fake.stats()
    assert num(st, "session_open") == 0
    assert num(st, "frames.close_session") == 1
    assert num(st, "handshakes") == 1
    s.close()  # idempotent
    assert num(fake.stats(), "frames.close_session") == 1


def test_exit_closes_on_an_exception(fake, key_file):
    with pytest.raises(ZeroDivisionError):
        with hc.Session(fake.address, key=key_file) as s:
            1 / 0
    assert s.closed
    assert num(fake.stats(), "session_open") == 0


def test_the_key_in_the_address_and_in_the_environment(fake, key_file, monkeypatch):
    with hc.Session(f"{fake.address}?key={key_file}") as s:
        assert s.authenticated
    monkeypatch.setenv("HAP_KEY_FILE", str(key_file))
    with hc.Session(fake.address) as s:
        assert s.authenticated
    assert num(fake.stats(), "handshakes") == 2


def test_link_passivity_by_keyword_and_by_address(fake, key_file):
    # Off by default; on with link_passivity=True or "?link=passive": the
    # position stream then carries this end's energy (CTRL_LINK_ENERGY).
    def frames(**kw):
        before = num(fake.stats(), "link_energy_frames")
        addr = kw.pop("addr", fake.address)
        with hc.Session(addr, key=key_file, **kw) as s:
            s.set_time_step(0.001)
            s.set_command_type("virtmech")
            s.attach_vo(0.5, [1e-3, 1e-3, 1e-3])
            for _ in range(20):
                s.set_speed([0.0] * 6)
                s.set_position([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        return num(fake.stats(), "link_energy_frames") - before

    assert frames() == 0
    assert frames(link_passivity=True) > 0
    assert frames(addr=f"{fake.address}?link=passive") > 0
    with pytest.raises(hc.AddressError):
        hc.Session(f"{fake.address}?link=active", key=key_file)


def test_configuration_reaches_the_controller(fake, key_file):
    with hc.Session(fake.address, key=key_file) as s:
        s.set_time_step(0.001)
        s.set_indexing_mode("all")
        s.set_command_type("virtmech")
        s.attach_vo(0.5, [1e-3, 1e-3, 1e-3])
        s.set_power_on(True)
        st = fake.stats()
        assert num(st, "command_type") == 2
        assert num(st, "powered") == 1
        assert num(st, "attached") == 1
        assert s.wait_answer(2.0)
        assert s.power_on
        assert s.status & hc.STATUS_POWER_ON
        assert s.status & hc.STATUS_COUPLED
        s.set_power_on(False)
        assert num(fake.stats(), "powered") == 0


def test_numpy_shapes_dtypes_and_streaming(fake, key_file):
    with hc.Session(fake.address, key=key_file) as s:
        s.set_command_type("virtmech")
        s.attach_vo(0.5, np.array([1e-3, 1e-3, 1e-3], dtype=np.float32))
        s.set_power_on(True)
        assert s.wait_answer(2.0)
        for get, n in ((s.get_position, 7), (s.get_speed, 6), (s.get_force, 6)):
            v = get()
            assert isinstance(v, np.ndarray)
            assert v.shape == (n,)
            assert v.dtype == np.float64
        q = s.get_position()[3:]
        assert abs(np.linalg.norm(q) - 1.0) < 1e-4
        # Lists, tuples and float32 arrays are accepted.
        s.set_speed([0.0] * 6)
        pose = (0.01, -0.02, 0.03, 0.0, 0.0, 0.0, 1.0)
        s.set_position(np.array(pose, dtype=np.float32))
        s.set_position(list(pose))
        # The set-points are not acknowledged: wait until the fake saw both.
        deadline = time.monotonic() + 5.0
        while num(st := fake.stats(), "frames.vpr_stream") < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        got = [float(x) for x in st["last_vo_pose"].split(",")]
        assert np.allclose(got, pose, atol=1e-5)
        assert num(st, "frames.vpr_stream") == 2
        # The coupling force pulls the streamed object toward the handle.
        assert s.wait_answer(2.0)
        f = s.get_force()
        h = s.get_position()
        assert np.linalg.norm(f[:3]) > 1.0
        assert np.dot(f[:3], h[:3] - np.array(pose[:3])) > 0
        stats = s.link_stats()
        assert stats["answers"] > 0 and stats["vpr_sent"] == 2


def test_another_key_is_refused(fake, tmp_path):
    from conftest import write_key

    other = write_key(tmp_path / "other.key")
    with pytest.raises(hc.ControllerTimeoutError) as e:
        hc.Session(fake.address, key=other, reply_timeout=0.1, attempts=2)
    assert e.value.code == 6
    assert isinstance(e.value, TimeoutError)
    st = fake.stats()
    assert num(st, "refused.bad_tag") >= 2
    assert num(st, "handshakes") == 0
    assert num(st, "frames.open_session") == 0


def test_an_unauthenticated_client_is_refused(fake):
    with pytest.raises(hc.ControllerTimeoutError):
        hc.Session(fake.address, insecure=True, reply_timeout=0.1, attempts=2)
    st = fake.stats()
    assert num(st, "refused.unauthenticated_v1") >= 2
    assert num(st, "frames.open_session") == 0


def test_insecure_speaks_v1_to_an_insecure_controller(start_fake):
    f = start_fake(insecure=True)
    with hc.Session(f.address, insecure=True) as s:
        assert not s.authenticated
        assert s.wait_answer(2.0)


def test_the_user_guides_example_runs(fake, key_file, capsys):
    import re
    from pathlib import Path

    guide = (Path(__file__).resolve().parents[3] / "Documentation" / "userguide.md").read_text()
    section = guide[guide.index("## Python: the `hapticctrl` package") :]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    assert len(code.strip().splitlines()) == 10
    code = code.replace("192.168.7.2#5000?key=hap.key", f"{fake.address}?key={key_file}")
    code = code.replace("duration=5.0", "duration=0.3")
    exec(compile(code, "userguide.md", "exec"), {})
    assert "LoopStats(cycles=" in capsys.readouterr().out
    st = fake.stats()
    assert num(st, "frames.vpr_stream") > 100
    assert num(st, "session_open") == 0
