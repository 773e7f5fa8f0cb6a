#!/usr/bin/env python3
"""Tango, a follower rover of the leader–follower demonstration, in Python.

The same autonomy code as the Rust follower (``examples/leader_follower``, the thesis's
Fig. 26): every control period (0.1 s) Tango's Plan module polls for ``Command`` messages from
its leader (Charlie) and, when one came, switches its motion; its Act module then reports its
``Wheels`` to its virtual environment. With no new command it keeps the previous motion.
Which transport carries each message (in-process, UDP, TCP, emulated radio) is the fleet file's
business: this code never names one.

Messages (the same type ids and fields as the Rust ``Command`` and ``Wheels``, so the Rust
leader and virtual environment read them):

    Command  id 0  {code: int}              0 straight, 1 turn left, 2 stop
    Wheels   id 1  {left: float, right: float}

Run it against a fleet file, e.g. ``tango-udp.toml`` beside this file::

    python examples/python/tango.py examples/python/tango-udp.toml

and, from other terminals, play the virtual environment and the leader with the Rust CLI::

    hetcomm listen examples/python/tango-udp.toml --as VirtualEnv3
    hetcomm send examples/python/tango-udp.toml --as Charlie --to Tango --module Plan --type 0 --json '{"code": 1}'

Tango prints one line per command received and per change of wheel speeds.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass

import hetcomm


@hetcomm.message(id=0)
@dataclass
class Command:
    """What the leader tells a follower to do: 0 straight, 1 turn left, 2 stop."""

    code: int


@hetcomm.message(id=1)
@dataclass
class Wheels:
    """A rover's wheel speeds, reported to its virtual environment."""

    left: float
    right: float


STOP = 2


def wheels_for(code: int) -> Wheels:
    """Wheel speeds for a command code (Fig. 26): straight 1/1, left pivot -10/+10, stop 0/0."""
    if code == 1:
        return Wheels(-10.0, 10.0)
    if code == STOP:
        return Wheels(0.0, 0.0)
    return Wheels(1.0, 1.0)


class Follower:
    """A follower's autonomy code: poll for commands, act on them, report the wheels."""

    def __init__(self, comm: hetcomm.Comm, environment: str, command_module: str = "Plan",
                 act_module: str = "Act", world_module: str = "World") -> None:
        self.name = comm.name
        self.plan = comm.module(command_module)
        self.act = comm.module(act_module)
        self.environment = environment
        self.world_module = world_module
        self.wheels = wheels_for(0)  # every rover starts driving straight
        self.commands: list[int] = []

    def step(self) -> None:
        """One control step: take every waiting command, then report the wheels."""
        while True:
            received = self.plan.try_recv()
            if received is None:
                break
            message, envelope = received
            if not isinstance(message, Command):
                print(f"{self.name}: ignoring {message!r} from {envelope.source_system}", flush=True)
                continue
            self.commands.append(message.code)
            print(f"{self.name}: command {message.code} from {envelope.source_system}."
                  f"{envelope.source_module} (id {envelope.message_id})", flush=True)
            wheels = wheels_for(message.code)
            if wheels != self.wheels:
                print(f"{self.name}: wheels left={wheels.left} right={wheels.right}", flush=True)
            self.wheels = wheels
        # Periodic data: a lost report is replaced by the next one, so the outcome is not
        # waited for here.
        self.act.send(self.environment, self.world_module, self.wheels)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("fleet", help="the fleet file")
    p.add_argument("--as", dest="system", default="Tango", help="this rover's system name (default Tango)")
    p.add_argument("--env", default="VirtualEnv3", help="its virtual environment's system (default VirtualEnv3)")
    p.add_argument("--period", type=float, default=0.1, help="control period, seconds (default 0.1)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--exit-on-stop", action="store_true", help="exit after a stop command (code 2)")
    args = p.parse_args(argv)

    comm = hetcomm.Comm.open(args.fleet, args.system)
    rover = Follower(comm, args.env)
    endpoints = ", ".join(f"{t} {a or '(in-process)'}" for t, a in comm.endpoints)
    print(f"{rover.name}: ready on {endpoints}", flush=True)
    print(f"{rover.name}: wheels left={rover.wheels.left} right={rover.wheels.right}", flush=True)

    start = time.monotonic()
    next_step = start
    try:
        while args.duration is None or time.monotonic() - start < args.duration:
            rover.step()
            if args.exit_on_stop and rover.commands and rover.commands[-1] == STOP:
                break
            next_step += args.period
            time.sleep(max(0.0, next_step - time.monotonic()))
    except KeyboardInterrupt:
        pass
    # Let the last report reach the environment before the system closes.
    time.sleep(min(0.2, args.period * 2))
    print(f"{rover.name}: done after {len(rover.commands)} commands", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
