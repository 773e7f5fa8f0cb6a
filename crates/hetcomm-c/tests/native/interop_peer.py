#!/usr/bin/env python3
"""The Python side of the C/C++ interop tests (run by ctest through drive.py): system ``Peer``
of the fleet ``fleet.toml.in`` receives a ``Sample`` from the C++ system ``Cpp``, checks that
its bytes are exactly what Python writes for the same value, and sends back a changed
``Sample``, acknowledged; it exits 0 only if that send was delivered.

    python interop_peer.py FLEET
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import List

import hetcomm


@hetcomm.message(id=7)
@dataclass
class Sample:
    """The same fields and id as the C++ Sample (interop.cpp) and the Rust one."""

    name: str
    x: float
    count: int
    values: List[int]
    ok: bool


def main() -> int:
    comm = hetcomm.Comm.open(sys.argv[1], "Peer")
    m = comm.module("M")
    print("ready", flush=True)
    raw = m.recv_raw(timeout=20)
    if raw.envelope.message_type != Sample.__hetcomm_id__:
        print(f"peer: type {raw.envelope.message_type} from C++", file=sys.stderr)
        return 1
    sample = raw.decode()
    if not isinstance(sample, Sample):
        print(f"peer: decoded {sample!r}, not a Sample", file=sys.stderr)
        return 1
    print(f"peer: got {sample} from {raw.envelope.source_system}", flush=True)
    ours = hetcomm.pack(sample)
    if ours != bytes(raw.payload):
        print(f"peer: C++ wrote {bytes(raw.payload).hex()}, Python writes {ours.hex()}", file=sys.stderr)
        return 1
    print("peer: bytes identical to Python's encoding", flush=True)
    reply = Sample(sample.name + " back", sample.x * 2, sample.count - 1,
                   sample.values + [len(sample.values)], not sample.ok)
    outcome = m.send("Cpp", "M", reply).wait(timeout=30)
    print(f"peer: reply {outcome}", flush=True)
    return 0 if outcome is not None and outcome.kind == "delivered" else 1


if __name__ == "__main__":
    sys.exit(main())
