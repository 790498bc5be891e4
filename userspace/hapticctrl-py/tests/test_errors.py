"""Every error path of the API mapped to its exception, with VirtuoseAPI's
code and the library's message."""

from __future__ import annotations

import contextlib
import os
import time

import numpy as np
import pytest

import hapticctrl as hc


def test_no_key_is_refused_before_anything_is_sent(fake):
    with pytest.raises(hc.NoKeyError) as e:
        hc.Session(fake.address)
    assert e.value.code == 4
    assert "HAP_KEY_FILE" in e.value.message
    assert "frames.open_session" not in fake.stats()


@pytest.mark.parametrize("address", ["127.0.0.1#x", "127.0.0.1#70000", "#5000", "", "127.0.0.1#5000?kex=/k"])
def test_bad_addresses(address, key_file):
    with pytest.raises(hc.AddressError) as e:
        hc.Session(address, key=key_file)
    assert e.value.code == 10
    assert isinstance(e.value, ValueError)
    assert e.value.message.startswith("invalid address")


def test_socket_error(key_file):
    # Sending to the broadcast address without SO_BROADCAST: EACCES.
    with pytest.raises(hc.CommunicationError) as e:
        hc.Session("255.255.255.255#5000", key=key_file, reply_timeout=0.05, attempts=1)
    assert e.value.code == 2
    assert "socket error" in e.value.message


def test_nobody_answers(key_file):
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as quiet:
        quiet.bind(("127.0.0.1", 0))
        port = quiet.getsockname()[1]
        with pytest.raises(hc.ControllerTimeoutError) as e:
            hc.Session(f"127.0.0.1#{port}", key=key_file, reply_timeout=0.05, attempts=2)
    assert e.value.code == 6
    assert "open_session" in e.value.message


def test_a_key_readable_by_others_is_refused(fake, key_file):
    os.chmod(key_file, 0o644)
    with pytest.raises(hc.InvalidArgumentError) as e:
        hc.Session(fake.address, key=key_file)
    assert e.value.code == 9
    assert "chmod 600" in e.value.message
    with pytest.raises(hc.InvalidArgumentError) as e:
        hc.Session(f"{fake.address}?key={key_file}")
    assert "chmod 600" in e.value.message


def test_a_missing_key_file(fake, tmp_path):
    with pytest.raises(hc.InvalidArgumentError) as e:
        hc.Session(fake.address, key=tmp_path / "none.key")
    assert e.value.code == 9


def test_insecure_with_a_key_is_a_contradiction(fake, key_file):
    with pytest.raises(hc.InvalidArgumentError):
        hc.Session(fake.address, key=key_file, insecure=True)


def test_a_second_key_holder_takes_the_session_and_the_first_is_told(fake, key_file):
    # A proven handshake takes the session (protocol.md §7): the second key
    # holder gets it; the first is told (error 0x102) and its context closes.
    first = hc.Session(fake.address, key=key_file, reply_timeout=0.2, attempts=2)
    second = hc.Session(fake.address, key=key_file, reply_timeout=0.5, attempts=2)
    try:
        assert not second.closed
        told = None
        for _ in range(50):
            try:
                first.set_power_on(False)
            except hc.VirtuoseError as e:
                told = e
                break
            time.sleep(0.02)
        assert told is not None, "the replaced holder was never told"
        # An error with its code and text, every call but close() after.
        assert isinstance(told, hc.SessionEndedError), repr(told)
        assert isinstance(told, hc.CommunicationError)
        assert told.code == 2
        assert told.reason == 0x102
        assert "replaced" in told.reason_name
        assert "(0x102)" in told.message
        for call in (first.get_position, lambda: first.set_position([0, 0, 0, 0, 0, 0, 1])):
            with pytest.raises(hc.SessionEndedError) as e:
                call()
            assert e.value.reason == 0x102
        second.set_power_on(False)
    finally:
        second.close()
        with contextlib.suppress(hc.VirtuoseError):
            first.close()


def test_no_data_before_the_first_answer(start_fake, key_file):
    f = start_fake("--per-request")  # answers only set-points
    with hc.Session(f.address, key=key_file) as s:
        for get in (s.get_position, s.get_speed, s.get_force):
            with pytest.raises(hc.NoDataError) as e:
                get()
            assert e.value.code == 8
        with pytest.raises(hc.NoDataError):
            s.status
        assert not s.wait_answer(0.05)
        # The answer to a set-point may come before wait_answer is called
        # (it waits for a newer one): stream until one is seen.
        for _ in range(40):
            s.set_position([0, 0, 0, 0, 0, 0, 1])
            if s.wait_answer(0.05):
                break
        assert s.get_position().shape == (7,)


@pytest.mark.parametrize(
    "call",
    [
        lambda s: s.set_time_step(0.0),
        lambda s: s.set_time_step(2.0),
        lambda s: s.set_force_factor(-1.0),
        lambda s: s.set_speed_factor(float("nan")),
        lambda s: s.attach_vo(0.0, [1e-3] * 3),
        lambda s: s.attach_vo(1.0, [1e-3] * 2),
        lambda s: s.set_position([0.0] * 6),
        lambda s: s.set_position([np.nan, 0, 0, 0, 0, 0, 1]),
        lambda s: s.set_position([0, 0, 0, 0, 0, 0, 0]),
        lambda s: s.set_speed(np.zeros(7)),
        lambda s: s.set_base_frame([0.0] * 3),
        lambda s: s.set_command_type("bogus"),
        lambda s: s.set_indexing_mode("sideways"),
        lambda s: s.wait_answer(-1.0),
        lambda s: s.run_loop(lambda t: None),
        lambda s: s.run_loop(lambda t: None, period=0.0, cycles=1),
        lambda s: s.run_loop(42, cycles=1),
        lambda s: s.run_loop(lambda t: "what", cycles=1),
        lambda s: s.run_loop(lambda t: ([0.0] * 3, [0.0] * 6), cycles=1),
    ],
)
def test_invalid_arguments(fake, key_file, call):
    with hc.Session(fake.address, key=key_file) as s:
        with pytest.raises(hc.InvalidArgumentError) as e:
            call(s)
        assert e.value.code == 9
        assert isinstance(e.value, ValueError)
        # The session is still usable.
        s.set_power_on(True)


def test_calls_after_close(fake, key_file):
    s = hc.Session(fake.address, key=key_file)
    s.close()
    for call in (
        lambda: s.get_position(),
        lambda: s.set_power_on(True),
        lambda: s.set_position([0, 0, 0, 0, 0, 0, 1]),
        lambda: s.wait_answer(0.1),
        lambda: s.run_loop(lambda t: None, cycles=1),
        lambda: s.session_id,
    ):
        with pytest.raises(hc.ClosedError) as e:
            call()
        assert e.value.code == 3


def test_a_request_the_controller_does_not_acknowledge(fake, key_file):
    with hc.Session(fake.address, key=key_file, reply_timeout=0.05, attempts=2) as s:
        fake.cut()
        with pytest.raises(hc.ControllerTimeoutError) as e:
            s.set_power_on(True)
        assert e.value.code == 6
        assert "power_request" in e.value.message
        fake.restore()


def test_error_messages_are_virtuose_apis():
    assert hc.error_message(6) == "time-out: no reply from the controller"
    assert hc.error_message(0) == "no error"
    assert hc.error_message(999) == "unknown error code"
    assert issubclass(hc.ControllerTimeoutError, hc.VirtuoseError)
    e = hc.RefusedError(17, "m", reason=1, reason_name="x", request="r")
    assert str(e) == "m (VirtuoseAPI error 17)"
