"""The `secured_frames` section of docs/wire-vectors.json, checked by a port of the document's
"Secured frames" section written from the document alone: the Noise KK handshake (X25519,
SHA-256, AES-256-GCM, HKDF as in the Noise specification) from the stated static and ephemeral
private keys, the split keys, every sealed data frame (AES-256-GCM, nonce 4 zero bytes + the
counter little-endian, associated data the 20 clear bytes; a data batch's records), and the
receiver's checks in the documented order for every frame of `received`.

The primitives come from the `cryptography` package (scripts/test-python.sh installs it); the
protocol around them is here, in a few dozen lines, and uses nothing of hetcomm."""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import struct
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric.x25519 import X25519PrivateKey, X25519PublicKey
from cryptography.hazmat.primitives.ciphers.aead import AESGCM
from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

ROOT = Path(os.environ.get("HETCOMM_ROOT", Path(__file__).resolve().parents[3]))
SECURED = json.loads((ROOT / "docs" / "wire-vectors.json").read_text())["secured_frames"]

PROTOCOL = b"Noise_KK_25519_AESGCM_SHA256"
PREFIX = struct.Struct("<2sBBHH")  # "HS", version, type, sender, receiver: 8 bytes
DATA = struct.Struct("<2sBBHHIQ")  # + the receiver's session index and the counter: 20 bytes
TAG = 16
WINDOW = 8192 - 64


def public_of(private: bytes) -> bytes:
    return X25519PrivateKey.from_private_bytes(private).public_key().public_bytes(Encoding.Raw, PublicFormat.Raw)


def dh(private: bytes, public: bytes) -> bytes:
    return X25519PrivateKey.from_private_bytes(private).exchange(X25519PublicKey.from_public_bytes(public))


def hkdf2(ck: bytes, ikm: bytes) -> tuple[bytes, bytes]:
    temp = hmac.new(ck, ikm, hashlib.sha256).digest()
    out1 = hmac.new(temp, b"\x01", hashlib.sha256).digest()
    out2 = hmac.new(temp, out1 + b"\x02", hashlib.sha256).digest()
    return out1, out2


class Symmetric:
    """The Noise SymmetricState with AESGCM (Noise nonces: 4 zero bytes + u64 big-endian)."""

    def __init__(self, prologue: bytes):
        self.h = PROTOCOL.ljust(32, b"\0")
        self.ck = self.h
        self.k = None
        self.n = 0
        self.mix_hash(prologue)

    def mix_hash(self, data: bytes) -> None:
        self.h = hashlib.sha256(self.h + data).digest()

    def mix_key(self, ikm: bytes) -> None:
        self.ck, self.k = hkdf2(self.ck, ikm)
        self.n = 0

    def encrypt_and_hash(self, plain: bytes) -> bytes:
        c = AESGCM(self.k).encrypt(b"\0" * 4 + self.n.to_bytes(8, "big"), plain, self.h)
        self.n += 1
        self.mix_hash(c)
        return c

    def split(self) -> tuple[bytes, bytes]:
        return hkdf2(self.ck, b"")


def noise_kk(h: dict, keys: dict) -> tuple[bytes, bytes, bytes, bytes, bytes]:
    """Both Noise messages, the handshake hash and the two split keys, from the document."""
    si, sr = keys[h["initiator"]], keys[h["responder"]]
    ei = bytes.fromhex(h["initiator_ephemeral_private_hex"])
    er = bytes.fromhex(h["responder_ephemeral_private_hex"])
    prologue = b"hetcomm-secure-v1" + struct.pack("<HH", h["initiator"], h["responder"])
    assert prologue.hex() == h["prologue_hex"]
    st = Symmetric(prologue)
    st.mix_hash(public_of(si))  # pre-message  -> s
    st.mix_hash(public_of(sr))  # pre-message  <- s
    # -> e, es, ss; payload: the initiator's timestamp, u64 little-endian
    st.mix_hash(public_of(ei))
    st.mix_key(dh(ei, public_of(sr)))
    st.mix_key(dh(si, public_of(sr)))
    m1 = public_of(ei) + st.encrypt_and_hash(struct.pack("<Q", h["timestamp"]))
    # <- e, ee, se; empty payload
    st.mix_hash(public_of(er))
    st.mix_key(dh(er, public_of(ei)))
    st.mix_key(dh(er, public_of(si)))
    m2 = public_of(er) + st.encrypt_and_hash(b"")
    k1, k2 = st.split()
    return m1, m2, st.h, k1, k2


def private_keys() -> dict:
    return {s["system"]: bytes.fromhex(s["private_key_hex"]) for s in SECURED["systems"]}


def test_public_keys() -> None:
    import base64

    for s in SECURED["systems"]:
        public = public_of(bytes.fromhex(s["private_key_hex"]))
        assert public.hex() == s["public_key_hex"]
        assert base64.b64encode(public).decode() == s["public_key_base64"]


def test_handshake_and_split_keys() -> None:
    h = SECURED["handshake"]
    m1, m2, hh, k1, k2 = noise_kk(h, private_keys())
    init = PREFIX.pack(b"HS", 1, 1, h["initiator"], h["responder"]) + struct.pack("<I", h["initiator_index"])
    resp = PREFIX.pack(b"HS", 1, 2, h["responder"], h["initiator"]) + struct.pack(
        "<II", h["responder_index"], h["initiator_index"]
    )
    assert (init + m1).hex() == h["initiation_hex"]
    assert (resp + m2).hex() == h["response_hex"]
    assert hh.hex() == h["handshake_hash_hex"]
    assert k1.hex() == h["key_initiator_to_responder_hex"]
    assert k2.hex() == h["key_responder_to_initiator_hex"]


def seal(key: bytes, kind: int, sender: int, receiver: int, index: int, counter: int, inner: bytes) -> bytes:
    clear = DATA.pack(b"HS", 1, kind, sender, receiver, index, counter)
    nonce = b"\0" * 4 + struct.pack("<Q", counter)
    return clear + AESGCM(key).encrypt(nonce, inner, clear)


@pytest.mark.parametrize("v", SECURED["sealed"], ids=[v["name"] for v in SECURED["sealed"]])
def test_sealed(v: dict) -> None:
    key = bytes.fromhex(SECURED["handshake"]["key_" + v["key"] + "_hex"])
    assert v["nonce_hex"] == (b"\0" * 4 + struct.pack("<Q", v["counter"])).hex()
    out = seal(
        key, v["type"], v["sender"], v["receiver"], v["session_index"], v["counter"], bytes.fromhex(v["inner_hex"])
    )
    assert out.hex() == v["secured_hex"]


class Receiver:
    """A receiver as the document describes it, holding the vector's session."""

    def __init__(self, spec: dict):
        h = SECURED["handshake"]
        self.local = spec["system"]
        self.peers = set(spec["peers"])
        self.data_from = set(spec["data_from"])
        self.acks_from = set(spec["acks_from"])
        initiator = self.local == h["initiator"]
        self.my_index = h["initiator_index"] if initiator else h["responder_index"]
        direction = "responder_to_initiator" if initiator else "initiator_to_responder"
        self.key = bytes.fromhex(h["key_" + direction + "_hex"])
        self.top = None  # the highest counter accepted
        self.seen = set()

    def receive(self, frame: bytes) -> tuple[str, bytes]:
        if len(frame) < 8:
            return "rejected_auth", b""
        magic, version, kind, sender, receiver = PREFIX.unpack_from(frame)
        if magic != b"HS" or version != 1 or kind not in (1, 2, 3, 4):
            return "rejected_auth", b""
        if receiver != self.local:
            return "rejected_table", b""
        if sender not in self.peers:
            return "rejected_unknown_sender", b""
        assert kind in (3, 4), "the vectors hold data messages and data batches only"
        if len(frame) < DATA.size + TAG:
            return "rejected_auth", b""
        index, counter = struct.unpack_from("<IQ", frame, 8)
        if index != self.my_index:
            return "rejected_no_session", b""
        try:
            plain = AESGCM(self.key).decrypt(b"\0" * 4 + struct.pack("<Q", counter), frame[20:], frame[:20])
        except Exception:
            return "rejected_auth", b""
        if counter in self.seen or (self.top is not None and counter < self.top and self.top - counter >= WINDOW):
            return "rejected_replay", b""
        self.seen.add(counter)
        self.top = counter if self.top is None else max(self.top, counter)
        if kind == 3:
            return self.check_inner(sender, plain)
        # A data batch: records (u32 length, at least 1, then the frame) to the end; each frame
        # is checked on its own, and what passes is handed up (here: one after the other).
        handed, verdict, at = b"", "rejected_table", 0
        while at < len(plain):
            (length,) = struct.unpack_from("<I", plain, at) if at + 4 <= len(plain) else (0,)
            if length == 0 or at + 4 + length > len(plain):
                return ("handed_up", handed) if handed else ("rejected_auth", b"")
            one, inner = self.check_inner(sender, plain[at + 4 : at + 4 + length])
            if one == "handed_up":
                handed, verdict = handed + inner, one
            at += 4 + length
        return verdict, handed

    def check_inner(self, sender: int, inner: bytes) -> tuple[str, bytes]:
        """Check 8 on one authenticated inner frame, and what is handed up."""
        if len(inner) >= 16 and inner[:2] == b"HC":
            kind, source, destination = inner[3], *struct.unpack_from("<H2xH", inner, 8)
            if source != sender or destination != self.local:
                return "rejected_table", b""
            if (kind == 0 and sender not in self.data_from) or (kind == 1 and sender not in self.acks_from):
                return "rejected_table", b""
        return ("handed_up", inner) if inner else ("accepted_empty", b"")


@pytest.mark.parametrize("v", SECURED["received"], ids=[v["name"] for v in SECURED["received"]])
def test_received(v: dict) -> None:
    spec = next(r for r in SECURED["receivers"] if r["system"] == v["receiver"])
    rx = Receiver(spec)
    sealed = {s["name"]: bytes.fromhex(s["secured_hex"]) for s in SECURED["sealed"]}
    for name in v["before"]:
        assert rx.receive(sealed[name])[0] in ("handed_up", "accepted_empty"), name
    verdict, inner = rx.receive(bytes.fromhex(v["secured_hex"]))
    assert verdict == v["verdict"]
    assert inner.hex() == v["inner_hex"]
