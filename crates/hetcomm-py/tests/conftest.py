"""Shared helpers: fleets, free ports, the `hetcomm` CLI as a child process whose output is
read line by line with deadlines (nothing sleeps to wait for readiness)."""

from __future__ import annotations

import os
import queue
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional

import pytest

import hetcomm

HERE = Path(__file__).resolve().parent
ROOT = Path(os.environ.get("HETCOMM_ROOT", HERE.parents[2]))
CLI = os.environ.get("HETCOMM_CLI", str(ROOT / "target" / "debug" / "hetcomm"))

INPROC_FLEET = """
name = "py-tests"
[systems]
Alpha = 0
Charlie = 1
Tango = 2
Lonely = 3

[modules]
Plan = 0
Act = 1
World = 2

[transports.wired]
kind = "inproc"

[table]
columns = ["Alpha", "Charlie", "Tango", "Lonely"]
Alpha   = ["X",     "wired",   "wired", "X"]
Charlie = ["wired", "X",       "wired", "X"]
Tango   = ["wired", "wired",   "X",     "X"]
Lonely  = ["X",     "X",       "X",     "X"]
"""


@hetcomm.message(id=0)
@dataclass
class Command:
    code: int


@hetcomm.message(id=1)
@dataclass
class Wheels:
    left: float
    right: float


@pytest.fixture
def fleet():
    with hetcomm.LocalFleet.from_toml(INPROC_FLEET, "py-tests.toml") as f:
        yield f


def free_ports(kind: str, count: int) -> List[int]:
    """`count` distinct free ports: every socket stays bound until all are picked, so the
    kernel cannot hand the same port out twice."""
    family = socket.SOCK_DGRAM if kind == "udp" else socket.SOCK_STREAM
    sockets = [socket.socket(socket.AF_INET, family) for _ in range(count)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


def ip_fleet(
    tmp_path: Path, kind: str, systems: List[str], name: str = "fleet.toml", secured: bool = True
) -> Path:
    """A fleet file where every pair of `systems` talks over one `kind` transport on loopback.

    Secured as a user would secure it: `hetcomm keygen` writes a key pair per system next to
    the file, and its `[security] keys` section points there. `secured=False` says
    `security = "none"` instead (for tests that speak raw frames)."""
    lines = [f'name = "py-{kind}"', "[systems]"]
    lines += [f"{s} = {i}" for i, s in enumerate(systems)]
    lines += ["[modules]", "Plan = 0", "Act = 1", "World = 2"]
    lines += ["[transports.lan]", f'kind = "{kind}"']
    if not secured:
        lines.append('security = "none"')
    lines += ["[transports.lan.endpoints]"]
    lines += [f'{s} = "127.0.0.1:{p}"' for s, p in zip(systems, free_ports(kind, len(systems)))]
    lines += ["[table]", "columns = [" + ", ".join(f'"{s}"' for s in systems) + "]"]
    for s in systems:
        row = ['"X"' if s == d else '"lan"' for d in systems]
        lines.append(f"{s} = [" + ", ".join(row) + "]")
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    if secured:
        keys = f"keys-{Path(name).stem}"
        made = cli("keygen", "--fleet", str(path), "--out", str(tmp_path / keys))
        assert made.returncode == 0, made
        with path.open("a") as f:
            f.write(f'[security]\nkeys = "{keys}"\n')
    return path


class Child:
    """A child process; stdout and stderr lines are queued by reader threads."""

    def __init__(self, args: List[str], **kw) -> None:
        self.args = args
        self.proc = subprocess.Popen(
            args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1, **kw
        )
        self.out: "queue.Queue[Optional[str]]" = queue.Queue()
        self.err: "queue.Queue[Optional[str]]" = queue.Queue()
        self.stdout_lines: List[str] = []
        self.stderr_lines: List[str] = []
        for stream, q, keep in ((self.proc.stdout, self.out, self.stdout_lines), (self.proc.stderr, self.err, self.stderr_lines)):
            threading.Thread(target=self._pump, args=(stream, q, keep), daemon=True).start()

    @staticmethod
    def _pump(stream, q, keep) -> None:
        for line in stream:
            keep.append(line.rstrip("\n"))
            q.put(line.rstrip("\n"))
        q.put(None)

    def _next(self, q, timeout: float, what: str) -> str:
        try:
            line = q.get(timeout=timeout)
        except queue.Empty:
            raise AssertionError(f"no {what} line within {timeout}s from {self.args}; stderr so far: {self.stderr_lines}")
        if line is None:
            raise AssertionError(f"{self.args} closed its {what} (exit {self.proc.poll()}); stderr: {self.stderr_lines}")
        return line

    def next_stdout(self, timeout: float = 15.0) -> str:
        return self._next(self.out, timeout, "stdout")

    def next_stderr(self, timeout: float = 15.0) -> str:
        return self._next(self.err, timeout, "stderr")

    def wait_stdout(self, predicate, timeout: float = 15.0) -> str:
        deadline = time.monotonic() + timeout
        while True:
            line = self.next_stdout(max(0.01, deadline - time.monotonic()))
            if predicate(line):
                return line

    def wait_stderr(self, predicate, timeout: float = 15.0) -> str:
        deadline = time.monotonic() + timeout
        while True:
            line = self.next_stderr(max(0.01, deadline - time.monotonic()))
            if predicate(line):
                return line

    def wait(self, timeout: float = 15.0) -> int:
        return self.proc.wait(timeout=timeout)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=5)


@pytest.fixture
def children():
    """Children started by a test; killed at its end whatever happens."""
    started: List[Child] = []

    def start(args: List[str], **kw) -> Child:
        c = Child(args, **kw)
        started.append(c)
        return c

    yield start
    for c in started:
        c.kill()


def cli(*args: str, timeout: float = 30.0) -> subprocess.CompletedProcess:
    """Runs the `hetcomm` CLI to completion."""
    return subprocess.run([CLI, *args], capture_output=True, text=True, timeout=timeout)


PYTHON = sys.executable


def udp_pair(extra: str = "", a: str = "127.0.0.1:0", b: str = "127.0.0.1:0") -> str:
    """Systems A and B with module M, joined by one UDP transport `lan` (`extra`: more keys).

    Unsecured (`security = "none"`): these fleets open one side alone, facing a silent or
    hand-made peer, to look at outcomes and errors (test_security.py covers secured ones)."""
    return f"""
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.lan]
kind = "udp"
security = "none"
{extra}
[transports.lan.endpoints]
A = "{a}"
B = "{b}"
[table]
columns = ["A", "B"]
A = ["X", "lan"]
B = ["lan", "X"]
"""
