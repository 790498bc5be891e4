"""Fixtures: the fake controller behind the bridge's authentication gate
(hapticctrl-fake, built by cargo) and a key file."""

from __future__ import annotations

import os
import secrets
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


def fake_binary() -> str:
    env = os.environ.get("HAPTICCTRL_FAKE")
    if env:
        return env
    for profile in ("release", "debug"):
        p = ROOT / "userspace" / "target" / profile / "hapticctrl-fake"
        if p.exists():
            return str(p)
    pytest.fail("hapticctrl-fake not built: cargo build --release -p hapticctrl-py --bin hapticctrl-fake")


def write_key(path: Path) -> Path:
    """A key file as `hapctl keygen` writes it: 64 hex digits, mode 0600."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(secrets.token_hex(32) + "\n")
    return path


class Fake:
    """A running hapticctrl-fake process."""

    def __init__(self, args: list[str]):
        self.proc = subprocess.Popen(
            [fake_binary(), *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        line = self.proc.stdout.readline()
        if not line.startswith("PORT "):
            err = self.proc.stderr.read()
            raise RuntimeError(f"hapticctrl-fake did not start: {line!r} {err}")
        self.port = int(line.split()[1])
        self.address = f"127.0.0.1#{self.port}"

    def command(self, cmd: str) -> None:
        self.proc.stdin.write(cmd + "\n")
        self.proc.stdin.flush()

    def cut(self) -> None:
        self.command("cut")

    def restore(self) -> None:
        self.command("restore")

    def _read_stats(self) -> dict[str, str]:
        out: dict[str, str] = {}
        for line in self.proc.stdout:
            line = line.strip()
            if line == "END":
                break
            k, _, v = line.partition(": ")
            out[k] = v
        return out

    def stats(self) -> dict[str, str]:
        self.command("stats")
        return self._read_stats()

    def stop(self) -> dict[str, str]:
        if self.proc.poll() is not None:
            return {}
        self.proc.stdin.close()
        s = self._read_stats()
        self.proc.wait(timeout=10)
        return s


def num(stats: dict[str, str], key: str) -> int:
    return int(stats.get(key, "0"))


@pytest.fixture
def key_file(tmp_path: Path) -> Path:
    return write_key(tmp_path / "hap.key")


@pytest.fixture
def start_fake(key_file: Path):
    fakes: list[Fake] = []

    def start(*extra: str, key: Path | None = key_file, insecure: bool = False) -> Fake:
        args = ["--insecure"] if insecure else ["--key", str(key)]
        f = Fake([*args, *extra])
        fakes.append(f)
        return f

    yield start
    for f in fakes:
        f.stop()


@pytest.fixture
def fake(start_fake) -> Fake:
    return start_fake()


@pytest.fixture(autouse=True)
def no_key_env(monkeypatch):
    """Tests give their keys explicitly."""
    monkeypatch.delenv("HAP_KEY_FILE", raising=False)
