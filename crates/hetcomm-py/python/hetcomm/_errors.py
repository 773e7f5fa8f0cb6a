"""The exceptions of hetcomm: one base class and one subclass per kind of error.

Their messages are those of the Rust library (a bad fleet file raises ConfigError whose message
is every problem found, each as ``file:line:column: message``).
"""

from __future__ import annotations

from typing import Any, Dict, List


class HetcommError(Exception):
    """Base class of every hetcomm error."""


class ConfigError(HetcommError):
    """The fleet file is invalid. ``errors`` lists each problem as a dict with ``file``,
    ``line``, ``column``, ``message`` and ``help`` (None when there is no suggestion)."""

    errors: List[Dict[str, Any]]

    def __init__(self, *args: object) -> None:
        super().__init__(*args)
        self.errors = []


class UnknownSystemError(HetcommError, LookupError):
    """No system of that name in the fleet."""


class UnknownModuleError(HetcommError, LookupError):
    """No module of that name in the fleet."""


class NoRouteError(HetcommError):
    """The communication table says X for this pair of systems: nothing was sent."""


class TooLargeError(HetcommError, ValueError):
    """The message is larger than the route's transport takes: nothing was sent."""


class BackpressureError(HetcommError):
    """The transport's ``max_in_flight`` sends (or ``max_in_flight_bytes``) to that system already await their outcome:
    nothing was sent. Wait for an earlier ticket's outcome and send again."""


class EncodeError(HetcommError, TypeError):
    """The message could not be encoded as a payload."""


class DecodeError(HetcommError, ValueError):
    """A payload could not be decoded (as its registered class)."""


class WrongTypeError(HetcommError, TypeError):
    """The next message is of another type than the one asked for; it stays in the inbox."""


class RecvTimeout(HetcommError, TimeoutError):
    """No message arrived in time (also a built-in ``TimeoutError``)."""


class ClosedError(HetcommError):
    """The system was closed."""


class TypeConflictError(HetcommError):
    """Two message classes claim the same type id."""


class TransportUnavailableError(HetcommError):
    """The fleet uses a transport kind that this build does not have yet."""


class TransportError(HetcommError, OSError):
    """A transport could not be opened (e.g. its port is taken)."""


__all__ = [
    "HetcommError",
    "ConfigError",
    "UnknownSystemError",
    "UnknownModuleError",
    "NoRouteError",
    "TooLargeError",
    "BackpressureError",
    "EncodeError",
    "DecodeError",
    "WrongTypeError",
    "RecvTimeout",
    "ClosedError",
    "TypeConflictError",
    "TransportUnavailableError",
    "TransportError",
]
