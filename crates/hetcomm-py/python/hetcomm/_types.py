"""Message classes: ``@hetcomm.message(id=N)`` on a dataclass, the process-wide registry of type
ids, and building instances from decoded payloads.

A message class is a dataclass with a type id. Its payload is a MessagePack map keyed by field
name, in declaration order: exactly what a Rust ``#[derive(Serialize, Deserialize, Message)]``
struct with the same fields and id writes, so both sides read each other's messages.

Decoding is as lenient as the Rust decoder: keys in any order, unknown keys ignored, a struct
written as an array of its fields, a missing ``Optional`` field read as None, an int accepted
for a float field. Nested dataclasses, ``List[X]``, ``Dict[K, V]``, ``Optional[X]``, ``Enum``
(from the variant name, as Rust writes unit variants) and ``bytes`` (from bin or an array of
ints, as Rust writes ``Vec<u8>``) fields are rebuilt from their annotations.

A class may instead define ``to_payload(self)`` (returning plain data: dict, list, int, …) and a
classmethod ``from_payload(cls, data)``, e.g. to match a Rust tuple or newtype struct.
"""

from __future__ import annotations

import dataclasses
import enum
import sys
import threading
import typing
from typing import Any, Callable, Dict, Optional, Tuple, Type, TypeVar, Union

from ._errors import DecodeError, TypeConflictError

T = TypeVar("T")

_lock = threading.Lock()
_by_id: Dict[int, type] = {}
_hints_cache: Dict[type, Dict[str, Any]] = {}

MAX_TYPE_ID = 0xFFFF_FFFF


@dataclasses.dataclass(frozen=True)
class UnknownMessage:
    """A message whose type id has no registered class: its ``type_id``, the payload decoded to
    plain Python values (``data``; None if the payload is not one MessagePack value) and the
    payload bytes. Sending it forwards it unchanged."""

    type_id: int
    data: Any
    payload: bytes


def _type_name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def register(cls: Type[T], id: Optional[int] = None) -> Type[T]:
    """Registers `cls` as the class of type id `id` (default: its ``__hetcomm_id__``).

    Raises TypeConflictError, naming both classes, if another class already has the id. A class
    with the same module and qualified name replaces the earlier one (a re-definition, e.g. a
    reloaded module)."""
    if id is None:
        id = getattr(cls, "__hetcomm_id__", None)
        if id is None:
            raise TypeError(f"{_type_name(cls)} has no message type id: decorate it with @hetcomm.message(id=N)")
    if isinstance(id, bool) or not isinstance(id, int) or not 0 <= id <= MAX_TYPE_ID:
        raise ValueError(f"message type id must be an int in 0..={MAX_TYPE_ID}, not {id!r}")
    if not (dataclasses.is_dataclass(cls) or (hasattr(cls, "to_payload") and hasattr(cls, "from_payload"))):
        raise TypeError(
            f"{_type_name(cls)} is not a dataclass (put @hetcomm.message above @dataclass), "
            "and does not define to_payload/from_payload"
        )
    with _lock:
        existing = _by_id.get(id)
        if existing is not None and existing is not cls and _type_name(existing) != _type_name(cls):
            raise TypeConflictError(
                f"message type id {id} is claimed by both `{_type_name(existing)}` and "
                f"`{_type_name(cls)}`: give one of them another id"
            )
        old_id = getattr(cls, "__hetcomm_id__", None)
        if old_id is not None and old_id != id and _by_id.get(old_id) is cls:
            del _by_id[old_id]
        cls.__hetcomm_id__ = id  # type: ignore[attr-defined]
        _by_id[id] = cls
        _hints_cache.pop(cls, None)
    return cls


def message(id: int) -> Callable[[Type[T]], Type[T]]:
    """Class decorator: declares a dataclass as the message type with type id `id` and
    registers it::

        @hetcomm.message(id=1)
        @dataclass
        class Wheels:
            left: float
            right: float
    """

    def wrap(cls: Type[T]) -> Type[T]:
        return register(cls, id)

    return wrap


def unregister(id: int) -> None:
    """Forgets the class registered for `id` (if any)."""
    with _lock:
        cls = _by_id.pop(id, None)
        if cls is not None:
            _hints_cache.pop(cls, None)


def registered(id: int) -> Optional[type]:
    """The class registered for type id `id`, or None."""
    with _lock:
        return _by_id.get(id)


def registered_types() -> Dict[int, type]:
    """A copy of the registry: {type id: class}."""
    with _lock:
        return dict(_by_id)


def type_id_of(cls_or_id: Union[type, int]) -> int:
    """The type id of a message class (registering it if needed) or an int id."""
    if isinstance(cls_or_id, int) and not isinstance(cls_or_id, bool):
        if not 0 <= cls_or_id <= MAX_TYPE_ID:
            raise ValueError(f"message type id must be in 0..={MAX_TYPE_ID}, not {cls_or_id}")
        return cls_or_id
    if not isinstance(cls_or_id, type):
        raise TypeError(f"expected a message class or a type id, not {cls_or_id!r}")
    type_id = getattr(cls_or_id, "__hetcomm_id__", None)
    if type_id is None:
        raise TypeError(f"{_type_name(cls_or_id)} has no message type id: decorate it with @hetcomm.message(id=N)")
    if registered(type_id) is not cls_or_id:
        register(cls_or_id, type_id)
    return int(type_id)


# --- called by the native module ---------------------------------------------------------


def prepare(msg: Any) -> Tuple[int, Optional[bytes]]:
    """(type id, payload or None) of a message to send; None means "pack the object itself"."""
    if isinstance(msg, UnknownMessage):
        return msg.type_id, bytes(msg.payload)
    cls = type(msg)
    if isinstance(msg, type) or getattr(cls, "__hetcomm_id__", None) is None:
        raise TypeError(
            f"cannot send {msg!r}: not an instance of a message class (decorate its class with "
            "@hetcomm.message(id=N), or use send_raw with a type id and payload bytes)"
        )
    type_id = type_id_of(cls)
    to_payload = getattr(msg, "to_payload", None)
    if to_payload is not None:
        from ._hetcomm import pack

        return type_id, bytes(pack(to_payload()))
    return type_id, None


def decode_message(type_id: int, data: Any, payload: bytes, error: Optional[str]) -> Any:
    """The message object for a received payload: an instance of the registered class, else an
    UnknownMessage."""
    cls = registered(type_id)
    if cls is None:
        return UnknownMessage(type_id, data, payload)
    if error is not None:
        raise DecodeError(error.replace("cannot decode payload", f"cannot decode payload as {cls.__qualname__}", 1))
    return build(cls, data)


# --- building instances --------------------------------------------------------------------


def _hints(cls: type) -> Dict[str, Any]:
    hints = _hints_cache.get(cls)
    if hints is None:
        try:
            hints = typing.get_type_hints(cls)
        except Exception:  # unresolvable forward references: fall back to no conversion
            hints = {}
        _hints_cache[cls] = hints
    return hints


def _allows_none(hint: Any) -> bool:
    if hint is Any or hint is type(None) or hint is None:
        return True
    origin = typing.get_origin(hint)
    if origin is Union or (sys.version_info >= (3, 10) and _is_union_type(hint)):
        return type(None) in typing.get_args(hint)
    return False


def _is_union_type(hint: Any) -> bool:
    import types

    return isinstance(hint, getattr(types, "UnionType", ()))


def build(cls: Type[T], data: Any) -> T:
    """Builds an instance of message (or nested dataclass) class `cls` from decoded data."""
    from_payload = getattr(cls, "from_payload", None)
    if from_payload is not None:
        try:
            return from_payload(data)  # type: ignore[no-any-return]
        except DecodeError:
            raise
        except Exception as e:
            raise DecodeError(f"cannot decode payload as {cls.__qualname__}: {e}") from e
    return _build_dataclass(cls, data, cls.__qualname__)


def _build_dataclass(cls: Type[T], data: Any, path: str) -> T:
    fields = [f for f in dataclasses.fields(cls) if f.init]  # type: ignore[arg-type]
    hints = _hints(cls)
    if isinstance(data, (list, tuple)):
        if len(data) > len(fields):
            raise DecodeError(f"cannot decode payload as {path}: array of {len(data)} elements for {len(fields)} fields")
        data = {f.name: v for f, v in zip(fields, data)}
    if not isinstance(data, dict):
        raise DecodeError(f"cannot decode payload as {path}: expected a map of fields, found {type(data).__name__} {data!r}")
    kwargs: Dict[str, Any] = {}
    for f in fields:
        hint = hints.get(f.name, Any)
        if f.name in data:
            kwargs[f.name] = _convert(data[f.name], hint, f"{path}.{f.name}")
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            if _allows_none(hint):
                kwargs[f.name] = None
            else:
                raise DecodeError(f"cannot decode payload as {path}: missing field `{f.name}`")
    try:
        return cls(**kwargs)
    except Exception as e:
        raise DecodeError(f"cannot decode payload as {path}: {e}") from e


def _convert(value: Any, hint: Any, path: str) -> Any:
    if hint is Any or isinstance(hint, TypeVar):
        return value
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is Union or _is_union_type(hint):
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, path)
            except DecodeError:
                continue
        return value
    if origin in (list, typing.List) and args:
        if not isinstance(value, (list, tuple)):
            raise DecodeError(f"cannot decode payload: {path} expected an array, found {value!r}")
        return [_convert(v, args[0], f"{path}[{i}]") for i, v in enumerate(value)]
    if origin in (tuple, typing.Tuple) and args:
        if not isinstance(value, (list, tuple)):
            raise DecodeError(f"cannot decode payload: {path} expected an array, found {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{path}[{i}]") for i, v in enumerate(value))
        return tuple(_convert(v, a, f"{path}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if origin in (dict, typing.Dict) and len(args) == 2:
        if not isinstance(value, dict):
            raise DecodeError(f"cannot decode payload: {path} expected a map, found {value!r}")
        return {_convert(k, args[0], path): _convert(v, args[1], f"{path}[{k!r}]") for k, v in value.items()}
    if origin is not None:
        return value
    if not isinstance(hint, type):
        return value
    if dataclasses.is_dataclass(hint):
        if hasattr(hint, "from_payload"):
            return build(hint, value)
        return _build_dataclass(hint, value, path)
    if issubclass(hint, enum.Enum):
        return _convert_enum(value, hint, path)
    if hint is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if hint is bytes and isinstance(value, list):
        try:
            return bytes(value)
        except (TypeError, ValueError) as e:
            raise DecodeError(f"cannot decode payload: {path}: {e}") from e
    return value


def _convert_enum(value: Any, hint: Type[enum.Enum], path: str) -> Any:
    if isinstance(value, dict) and len(value) == 1:
        (name, inner), = value.items()
        if inner is None:
            value = name
    if isinstance(value, str):
        try:
            return hint[value]
        except KeyError:
            pass
    try:
        return hint(value)
    except ValueError:
        pass
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(hint):
        return list(hint)[value]
    raise DecodeError(f"cannot decode payload: {path}: {value!r} is not a variant of {hint.__qualname__}")
