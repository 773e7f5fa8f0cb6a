"""A foreign system on an unsecured `shm` transport, written from docs/shm.md and
docs/wire-format.md with the `iceoryx2` Python package: system B answers every data frame
from A with a data frame of its own carrying the same payload.

    python shm_system.py SERVICE_PREFIX B_ID A_ID COUNT

SERVICE_PREFIX is `PREFIX/FLEET`; B listens on `SERVICE_PREFIX/B` and publishes on
`SERVICE_PREFIX/A`. It prints `ready` once its ports are open and `answered N` at the end.
"""

import ctypes
import struct
import sys
import zlib

import iceoryx2 as iox2

HEADER = struct.Struct("<2sBBBBBBHHHHIQIQII")
FLAG_HEADER_CRC = 0x04


def crc_of(frame: bytearray, header_only: bool) -> int:
    covered = bytearray(frame[:48] if header_only else frame)
    covered[44:48] = b"\0\0\0\0"
    return zlib.crc32(covered) & 0xFFFFFFFF


def check(frame: bytes):
    """The header's fields, after the checks docs/wire-format.md asks of a receiver."""
    if len(frame) < 48:
        raise ValueError(f"{len(frame)} bytes: shorter than a header")
    f = HEADER.unpack_from(frame)
    magic, version, kind, flags = f[0], f[1], f[2], f[3]
    if magic != b"HC" or version != 1 or kind != 0:
        raise ValueError(f"not a version-1 data frame: {magic!r} {version} {kind}")
    if flags & 0xE0:
        raise ValueError(f"undefined flags {flags:#x}")
    payload_len, crc = f[-2], f[-1]
    if payload_len != len(frame) - 48:
        raise ValueError(f"payload_len {payload_len}, {len(frame) - 48} bytes present")
    if crc_of(bytearray(frame), bool(flags & FLAG_HEADER_CRC)) != crc:
        raise ValueError("bad CRC")
    return f


def answer(f, payload: bytes, seq: int) -> bytes:
    """A data frame from B's module back to A's, unacknowledged, full CRC."""
    (_m, _v, _k, _fl, prio, transport, _r, src_sys, src_mod, dst_sys, dst_mod,
     _inc, _seq, mtype, ts, _len, _crc) = f
    frame = bytearray(HEADER.pack(b"HC", 1, 0, 0, prio, transport, 0, dst_sys, dst_mod,
                                  src_sys, src_mod, 4242, seq, mtype, ts, len(payload), 0))
    frame += payload
    struct.pack_into("<I", frame, 44, crc_of(frame, False))
    return bytes(frame)


def main():
    prefix, count = sys.argv[1], int(sys.argv[4])
    iox2.set_log_level_from_env_or(iox2.LogLevel.Fatal)
    node = (iox2.NodeBuilder.new()
            .name(iox2.NodeName.new(f"{prefix}/B"))
            .create(iox2.ServiceType.Ipc))

    def pubsub(name):
        # Opened, not created: hetcomm's A created both with the transport's limits.
        return (node.service_builder(iox2.ServiceName.new(name))
                .publish_subscribe(iox2.Slice[ctypes.c_uint8]).open())

    def event(name):
        return node.service_builder(iox2.ServiceName.new(name)).event().open()

    subscriber = pubsub(f"{prefix}/B").subscriber_builder().create()
    listener = event(f"{prefix}/B").listener_builder().create()
    publisher = (pubsub(f"{prefix}/A").publisher_builder()
                 .initial_max_slice_len(4096).create())
    notifier = event(f"{prefix}/A").notifier_builder().create()
    print("ready", flush=True)
    answered = 0
    while answered < count:
        listener.timed_wait(iox2.Duration.from_millis(100))
        while True:
            sample = subscriber.receive()
            if sample is None:
                break
            data = sample.payload()
            frame = bytes(data[i] for i in range(data.len()))
            f = check(frame)
            reply = answer(f, frame[48:], answered + 1)
            out = publisher.loan_slice_uninit(len(reply))
            for i, b in enumerate(reply):
                out.payload()[i] = b
            out.assume_init().send()
            notifier.notify()
            answered += 1
    print(f"answered {answered}", flush=True)


if __name__ == "__main__":
    main()
