"""hetcomm — a heterogeneous communication layer for teams of robots (Python bindings).

Autonomy code sends user-defined messages to modules of other systems; a TOML fleet file
decides which transport (in-process, UDP, TCP, emulated radio, …) carries them::

    from dataclasses import dataclass
    import hetcomm

    @hetcomm.message(id=1)
    @dataclass
    class Wheels:
        left: float
        right: float

    comm = hetcomm.Comm.open("fleet.toml", "Tango")     # or hetcomm.LocalFleet.open_file(...)
    act = comm.module("Act")
    outcome = act.send("Env", "Sim", Wheels(-1.0, 1.0)).wait()
    message, envelope = act.recv(timeout=1.0)

Payloads use the language-neutral encoding of ``docs/wire-format.md`` (one MessagePack value,
structs as maps keyed by field name), so a Python class and a Rust type with the same type id
and fields exchange messages.
"""

from __future__ import annotations

from ._errors import (
    BackpressureError,
    ClosedError,
    ConfigError,
    DecodeError,
    EncodeError,
    HetcommError,
    NoRouteError,
    RecvTimeout,
    TooLargeError,
    TransportError,
    TransportUnavailableError,
    TypeConflictError,
    UnknownModuleError,
    UnknownSystemError,
    WrongTypeError,
)
from ._hetcomm import (
    BroadcastTicket,
    Comm,
    Envelope,
    LocalFleet,
    Module,
    Outcome,
    PathWatch,
    Publisher,
    RawMessage,
    Received,
    Replacement,
    ScenarioRun,
    Subscription,
    TapHandle,
    Ticket,
    TopicNotification,
    __version__,
    decode_frame,
    pack,
    unpack,
)
from ._types import (
    UnknownMessage,
    message,
    register,
    registered,
    registered_types,
    unregister,
)

#: Priorities: 0 lowest, 100 the default, 255 highest.
PRIORITY_LOWEST = 0
PRIORITY_NORMAL = 100
PRIORITY_HIGHEST = 255

__all__ = [
    "BackpressureError",
    "BroadcastTicket",
    "ClosedError",
    "Comm",
    "ConfigError",
    "DecodeError",
    "EncodeError",
    "Envelope",
    "HetcommError",
    "LocalFleet",
    "Module",
    "Publisher",
    "Replacement",
    "ScenarioRun",
    "Subscription",
    "TapHandle",
    "TopicNotification",
    "NoRouteError",
    "Outcome",
    "PathWatch",
    "PRIORITY_HIGHEST",
    "PRIORITY_LOWEST",
    "PRIORITY_NORMAL",
    "RawMessage",
    "Received",
    "RecvTimeout",
    "Ticket",
    "TooLargeError",
    "TransportError",
    "TransportUnavailableError",
    "TypeConflictError",
    "UnknownMessage",
    "UnknownModuleError",
    "UnknownSystemError",
    "WrongTypeError",
    "__version__",
    "decode_frame",
    "message",
    "pack",
    "register",
    "registered",
    "registered_types",
    "unpack",
    "unregister",
]
