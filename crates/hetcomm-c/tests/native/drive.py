#!/usr/bin/env python3
"""Runs the multi-process tests of the C/C++ suite for ctest (standard library only).

    drive.py interop --kind udp|tcp --cpp BIN --template fleet.toml.in --cli BIN -- PEER COMMAND...
        writes the fleet with two free ports, starts the peer command with the fleet path
        appended, waits for its "ready", runs the C++ program on the same fleet; both must
        exit 0 (each checks the outcome of its own acknowledged send).
    drive.py demo --tango BIN --cli BIN --fleet leader-follower-cpp.toml --out DIR
        the C++ Tango in place of the Rust one in `hetcomm demo --realtime --external Tango`:
        Tango must get the leader's four commands in order and the Rust virtual environment
        must log it making the same two left turns as the other rovers.
"""

from __future__ import annotations

import argparse
import os
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path


def free_ports(kind: str, count: int) -> list[int]:
    """`count` distinct free ports: every socket stays bound until all are picked, so the
    kernel cannot hand the same port out twice (it did, and two systems shared an endpoint)."""
    family = socket.SOCK_DGRAM if kind == "udp" else socket.SOCK_STREAM
    sockets = [socket.socket(socket.AF_INET, family) for _ in range(count)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


class Child:
    """A child process whose stdout lines are collected (and echoed) as they come."""

    def __init__(self, argv: list[str], name: str) -> None:
        self.name = name
        self.lines: list[str] = []
        self.cond = threading.Condition()
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, text=True, errors="replace")
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            line = line.rstrip("\n")
            print(f"[{self.name}] {line}", flush=True)
            with self.cond:
                self.lines.append(line)
                self.cond.notify_all()

    def wait_line(self, pred, timeout: float) -> str:
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                for line in self.lines:
                    if pred(line):
                        return line
                left = deadline - time.monotonic()
                if left <= 0 or self.proc.poll() is not None and not self._more_coming():
                    raise SystemExit(f"{self.name}: expected line not seen within {timeout} s "
                                     f"(exit code {self.proc.poll()})")
                self.cond.wait(min(left, 0.1))

    def _more_coming(self) -> bool:
        time.sleep(0.05)
        return False

    def wait(self, timeout: float) -> int:
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise SystemExit(f"{self.name}: still running after {timeout} s (killed)")

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def secure(cli: str, fleet: Path, keys: str = "keys") -> None:
    """Secures `fleet` as a user would: `hetcomm keygen` writes a key pair per system beside it,
    and its `[security] keys` section points there (unless the file names the folder already)."""
    made = subprocess.run([cli, "keygen", "--fleet", str(fleet), "--out", str(fleet.parent / keys)],
                          capture_output=True, text=True)
    if made.returncode != 0:
        raise SystemExit(f"hetcomm keygen failed: {made.stderr}")
    text = fleet.read_text()
    if "[security]" not in text:
        fleet.write_text(text + f'\n[security]\nkeys = "{keys}"\n')


def interop(args: argparse.Namespace) -> int:
    text = Path(args.template).read_text()
    port_cpp, port_peer = free_ports(args.kind, 2)
    text = (text.replace("@KIND@", args.kind)
            .replace("@PORT_CPP@", str(port_cpp))
            .replace("@PORT_PEER@", str(port_peer))
            .replace("@SETTINGS@", ""))
    with tempfile.TemporaryDirectory() as tmp:
        fleet = Path(tmp) / "fleet.toml"
        fleet.write_text(text)
        secure(args.cli, fleet)
        peer = Child(args.peer + [str(fleet)], "peer")
        try:
            peer.wait_line(lambda l: l == "ready", 30)
            cpp = Child([args.cpp, str(fleet)], "cpp")
            cpp_rc = cpp.wait(60)
            peer_rc = peer.wait(60)
        finally:
            peer.kill()
    print(f"cpp exit {cpp_rc}, peer exit {peer_rc}")
    if cpp_rc != 0 or peer_rc != 0:
        return 1
    if not any(l.startswith("peer: bytes identical") for l in peer.lines):
        print("the peer did not confirm the encoding")
        return 1
    return 0


def pose_rows(demo_stdout: str, rover: str) -> list[tuple[float, ...]]:
    """(t, x, y, theta) rows of a rover's location table printed by the demo."""
    block = demo_stdout.split(f"{rover} location data", 1)[1].split("\n\n", 1)[0]
    rows = []
    for line in block.splitlines()[2:]:
        fields = line.split()
        if len(fields) == 4:
            rows.append(tuple(float(f) for f in fields))
    return rows


def demo(args: argparse.Namespace) -> int:
    text = Path(args.fleet).read_text()
    olds = sorted(set(re.findall(r"127\.0\.0\.1:(\d+)", text)))
    for old, new in zip(olds, free_ports("udp", len(olds))):
        text = text.replace(f"127.0.0.1:{old}", f"127.0.0.1:{new}")
    with tempfile.TemporaryDirectory() as tmp:
        fleet = Path(tmp) / "fleet.toml"
        fleet.write_text(text)
        secure(args.cli, fleet)
        tango = Child([args.tango, str(fleet), "--duration", "30", "--exit-on-stop"], "tango")
        try:
            tango.wait_line(lambda l: l.startswith("Tango: ready on lan udp://127.0.0.1:"), 30)
            demo = Child([args.cli, "demo", "--realtime", "--fleet", str(fleet), "--external", "Tango",
                          "--out", args.out], "demo")
            demo_rc = demo.wait(90)
            tango_rc = tango.wait(40)
        finally:
            tango.kill()
    if demo_rc != 0 or tango_rc != 0:
        print(f"demo exit {demo_rc}, tango exit {tango_rc}")
        return 1
    codes = [int(l.split()[2]) for l in tango.lines if l.startswith("Tango: command ")]
    if codes != [1, 0, 1, 0]:
        print(f"Tango got commands {codes}, expected [1, 0, 1, 0]")
        return 1
    if not all("from Charlie.Plan" in l for l in tango.lines if l.startswith("Tango: command ")):
        print("a command did not come from Charlie.Plan")
        return 1
    rows = pose_rows("\n".join(demo.lines).replace("[demo] ", ""), "Tango")
    turns, turning = 0, False
    for (_, x0, y0, th0), (_, x1, y1, th1) in zip(rows, rows[1:]):
        moved = abs(x1 - x0) > 1e-6 or abs(y1 - y0) > 1e-6
        rotated = abs(th1 - th0) > 1e-6
        if rotated and not moved and not turning:
            turns += 1
        turning = rotated and not moved
    if len(rows) < 15 or turns != 2:
        print(f"the VE logged {len(rows)} Tango poses with {turns} pivots, expected >= 15 and 2")
        return 1
    print(f"C++ Tango followed: commands {codes}, {turns} pivots in {len(rows)} poses")
    return 0


def main() -> int:
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="cmd", required=True)
    i = sub.add_parser("interop")
    i.add_argument("--kind", choices=["udp", "tcp"], required=True)
    i.add_argument("--cpp", required=True)
    i.add_argument("--template", required=True)
    i.add_argument("--cli", required=True, help="the hetcomm CLI, for `hetcomm keygen`")
    i.add_argument("peer", nargs=argparse.REMAINDER)
    d = sub.add_parser("demo")
    d.add_argument("--tango", required=True)
    d.add_argument("--cli", required=True)
    d.add_argument("--fleet", required=True)
    d.add_argument("--out", required=True)
    args = p.parse_args()
    if args.cmd == "interop":
        if args.peer and args.peer[0] == "--":
            args.peer = args.peer[1:]
        if not args.peer:
            p.error("interop needs the peer command after --")
        return interop(args)
    return demo(args)


if __name__ == "__main__":
    sys.exit(main())
