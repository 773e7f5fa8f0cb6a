//! The secured frame on the wire (specified byte by byte in `docs/wire-format.md`, "Secured
//! frames"). Every frame a secured link carries is one of three messages, each starting with
//! the same 8 clear bytes:
//!
//! ```text
//! 0  2  magic "HS"
//! 2  1  version (1)
//! 3  1  type: 1 handshake initiation, 2 handshake response, 3 data
//! 4  2  sender system id (u16, little-endian)
//! 6  2  receiver system id (u16, little-endian)
//! ```
//!
//! Data (type 3): `8 u32` the receiver's session index, `12 u64` the counter (the AEAD
//! nonce), `20 …` the inner frame encrypted with AES-256-GCM, then the 16-byte tag. The 20
//! clear bytes are the associated data, so none of them can be changed either.
//!
//! Data batch (type 4): as data, but what is encrypted is several inner frames, each behind
//! its length (u32 little-endian): frames sent together cost one seal and one open.
//!
//! Initiation (type 1): `8 u32` the initiator's session index, `12 …` Noise KK message 1.
//! Response (type 2): `8 u32` the responder's session index, `12 u32` the initiator's
//! session index, `16 …` Noise KK message 2.

use hetcomm_core::SystemId;
use ring::aead::{Aad, LessSafeKey, Nonce, Tag, UnboundKey, AES_256_GCM};

/// The first two bytes of every secured frame.
pub const MAGIC: [u8; 2] = *b"HS";
/// The secured frame format's version.
pub const VERSION: u8 = 1;
/// Clear bytes in front of a data frame's ciphertext.
pub const DATA_HEADER_LEN: usize = 20;
/// Bytes of the authentication tag behind the ciphertext.
pub const TAG_LEN: usize = 16;
/// What securing adds to a frame.
pub const OVERHEAD: usize = DATA_HEADER_LEN + TAG_LEN;
/// The Noise protocol of the handshake.
pub const NOISE_PARAMS: &str = "Noise_KK_25519_AESGCM_SHA256";
/// Clear bytes in front of the Noise message in an initiation.
pub const INIT_HEADER_LEN: usize = 12;
/// Clear bytes in front of the Noise message in a response.
pub const RESPONSE_HEADER_LEN: usize = 16;

/// Which of the three secured messages a frame is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Noise KK message 1.
    Init = 1,
    /// Noise KK message 2.
    Response = 2,
    /// An encrypted inner frame.
    Data = 3,
    /// Encrypted inner frames, each behind its length.
    Batch = 4,
}

/// Bytes in front of each inner frame of a data batch: its length (u32 little-endian).
pub const RECORD_HEADER: usize = 4;

/// Appends `head` + `body` to a data batch's plaintext, behind its length.
pub fn push_record(records: &mut Vec<u8>, head: &[u8], body: &[u8]) {
    let len = u32::try_from(head.len() + body.len()).expect("frames are far below 4 GiB");
    records.extend_from_slice(&len.to_le_bytes());
    records.extend_from_slice(head);
    records.extend_from_slice(body);
}

/// The inner frames of a data batch's plaintext, as ranges of it. Stops at the first record
/// that is not well formed (empty, or running past the end; then [`Records::malformed`]).
pub struct Records<'a> {
    plain: &'a [u8],
    at: usize,
    /// A record was not well formed: it and what follows it are not frames.
    pub malformed: bool,
}

/// The records of `plain` (a data batch's plaintext).
pub fn records(plain: &[u8]) -> Records<'_> {
    Records {
        plain,
        at: 0,
        malformed: false,
    }
}

impl Iterator for Records<'_> {
    type Item = std::ops::Range<usize>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.at == self.plain.len() || self.malformed {
            return None;
        }
        let start = self.at + RECORD_HEADER;
        let len = (start <= self.plain.len()).then(|| u32_at(self.plain, self.at) as usize);
        match len {
            Some(len) if len > 0 && len <= self.plain.len() - start => {
                self.at = start + len;
                Some(start..start + len)
            }
            _ => {
                self.malformed = true;
                None
            }
        }
    }
}

/// The clear part every secured frame starts with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Prefix {
    /// Which message.
    pub kind: Kind,
    /// Who sent it (claimed; proven only by the message's authentication).
    pub sender: SystemId,
    /// Who it is for.
    pub receiver: SystemId,
}

/// Reads the clear prefix, or None if `frame` is not a secured frame of this version.
pub fn prefix(frame: &[u8]) -> Option<Prefix> {
    if frame.len() < 8 || frame[0..2] != MAGIC || frame[2] != VERSION {
        return None;
    }
    let kind = match frame[3] {
        1 => Kind::Init,
        2 => Kind::Response,
        3 => Kind::Data,
        4 => Kind::Batch,
        _ => return None,
    };
    Some(Prefix {
        kind,
        sender: SystemId(u16::from_le_bytes([frame[4], frame[5]])),
        receiver: SystemId(u16::from_le_bytes([frame[6], frame[7]])),
    })
}

/// Writes the 8-byte prefix.
pub fn write_prefix(out: &mut Vec<u8>, kind: Kind, sender: SystemId, receiver: SystemId) {
    out.extend_from_slice(&prefix_bytes(kind, sender, receiver));
}

/// The 8-byte prefix.
fn prefix_bytes(kind: Kind, sender: SystemId, receiver: SystemId) -> [u8; 8] {
    let [s0, s1] = sender.0.to_le_bytes();
    let [r0, r1] = receiver.0.to_le_bytes();
    [MAGIC[0], MAGIC[1], VERSION, kind as u8, s0, s1, r0, r1]
}

/// Reads a little-endian u32 at `at` (the caller checked the length).
pub fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// One direction's AES-256-GCM key (ring, the crate that also serves the Noise handshake's
/// AES-GCM and SHA-256: on x86-64 it uses vector AES and carry-less multiply with AVX2 where
/// present, 5.2 GB/s on the 2-core AMD EPYC without AVX-512 where aws-lc-rs ran its older
/// AES-NI code at 3.7; `examples/seal_speed.rs` measures it, and docs/security.md, "What it
/// costs", has the figures). ring seals and opens in place only, so a frame's plaintext is
/// copied into the frame's buffer and encrypted there.
pub struct DirectionKey(LessSafeKey);

impl DirectionKey {
    /// The key from 32 bytes (a half of the Noise handshake's split).
    pub fn new(bytes: &[u8; 32]) -> DirectionKey {
        DirectionKey(LessSafeKey::new(
            UnboundKey::new(&AES_256_GCM, bytes).expect("AES-256 takes 32-byte keys"),
        ))
    }

    fn nonce(counter: u64) -> Nonce {
        let mut n = [0; 12];
        n[4..].copy_from_slice(&counter.to_le_bytes());
        Nonce::assume_unique_for_key(n)
    }

    /// Makes `out` the data frame carrying `head` + `body` (whatever `out` held is replaced,
    /// without zeroing it first). `head` and `body` are copied into `out` once and encrypted
    /// there: no other buffer is made.
    pub fn seal(
        &self,
        out: &mut Vec<u8>,
        ids: (SystemId, SystemId),
        session: u32,
        counter: u64,
        head: &[u8],
        body: &[u8],
    ) {
        self.seal_kind(out, Kind::Data, ids, (session, counter), head, body);
    }

    /// Makes `out` the data batch carrying `records` (see [`push_record`]).
    pub fn seal_batch(
        &self,
        out: &mut Vec<u8>,
        ids: (SystemId, SystemId),
        session: u32,
        counter: u64,
        records: &[u8],
    ) {
        self.seal_kind(out, Kind::Batch, ids, (session, counter), records, &[]);
    }

    fn seal_kind(
        &self,
        out: &mut Vec<u8>,
        kind: Kind,
        (sender, receiver): (SystemId, SystemId),
        (session, counter): (u32, u64),
        head: &[u8],
        body: &[u8],
    ) {
        // Only the bytes beyond the buffer's earlier length are zeroed (a reused scratch
        // buffer is already long enough), and every byte is overwritten below.
        out.resize(OVERHEAD + head.len() + body.len(), 0);
        let (clear, rest) = out.split_at_mut(DATA_HEADER_LEN);
        clear[..8].copy_from_slice(&prefix_bytes(kind, sender, receiver));
        clear[8..12].copy_from_slice(&session.to_le_bytes());
        clear[12..].copy_from_slice(&counter.to_le_bytes());
        let (plain, tag_out) = rest.split_at_mut(head.len() + body.len());
        plain[..head.len()].copy_from_slice(head);
        plain[head.len()..].copy_from_slice(body);
        let tag = self
            .0
            .seal_in_place_separate_tag(Self::nonce(counter), Aad::from(&*clear), plain)
            .expect("AES-GCM seals any frame under 64 GiB");
        tag_out.copy_from_slice(tag.as_ref());
    }

    /// Decrypts a data frame in place: on success the inner frame is
    /// `frame[DATA_HEADER_LEN..len - TAG_LEN]`. False if it does not authenticate.
    pub fn open(&self, frame: &mut [u8]) -> bool {
        if frame.len() < OVERHEAD {
            return false;
        }
        let counter = data_counter(frame);
        let (clear, rest) = frame.split_at_mut(DATA_HEADER_LEN);
        let (cipher, tag) = rest.split_at_mut(rest.len() - TAG_LEN);
        let tag = Tag::try_from(&*tag).expect("TAG_LEN bytes");
        self.0
            .open_in_place_separate_tag(Self::nonce(counter), Aad::from(&*clear), tag, cipher, 0..)
            .is_ok()
    }

    /// Decrypts a data frame into `out`, which must be [`inner_len`] bytes long; the frame
    /// itself is only read (its ciphertext is copied into `out` and opened there). False if it
    /// does not authenticate (`out` then holds garbage).
    pub fn open_into(&self, frame: &[u8], out: &mut [u8]) -> bool {
        if frame.len() < OVERHEAD || out.len() != frame.len() - OVERHEAD {
            return false;
        }
        let (clear, rest) = frame.split_at(DATA_HEADER_LEN);
        let (cipher, tag) = rest.split_at(rest.len() - TAG_LEN);
        let tag = Tag::try_from(tag).expect("TAG_LEN bytes");
        out.copy_from_slice(cipher);
        self.0
            .open_in_place_separate_tag(
                Self::nonce(data_counter(frame)),
                Aad::from(clear),
                tag,
                out,
                0..,
            )
            .is_ok()
    }
}

/// The length of the inner frame a data frame of `frame_len` bytes carries (0 if it is too
/// short to be one).
pub fn inner_len(frame_len: usize) -> usize {
    frame_len.saturating_sub(OVERHEAD)
}

/// The counter of a data frame (the caller checked the length).
pub fn data_counter(frame: &[u8]) -> u64 {
    u64::from_le_bytes(frame[12..20].try_into().expect("8 bytes"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batches_seal_and_their_records_read_back() {
        let key = DirectionKey::new(&[7; 32]);
        let mut plain = Vec::new();
        push_record(&mut plain, b"one", b"");
        push_record(&mut plain, b"tw", b"o");
        let mut out = Vec::new();
        key.seal_batch(&mut out, (SystemId(1), SystemId(2)), 9, 4, &plain);
        assert_eq!(prefix(&out).unwrap().kind, Kind::Batch);
        let mut inner = vec![0; inner_len(out.len())];
        assert!(key.open_into(&out, &mut inner));
        let mut r = records(&inner);
        let got: Vec<&[u8]> = r.by_ref().map(|x| &inner[x]).collect();
        assert_eq!(got, [&b"one"[..], b"two"]);
        assert!(!r.malformed);
        // The type is authenticated: a batch does not open as a single frame.
        out[3] = Kind::Data as u8;
        assert!(!key.open_into(&out, &mut inner));
        for bad in [&[1, 0, 0][..], &[0, 0, 0, 0], &[5, 0, 0, 0, 1, 2]] {
            let mut r = records(bad);
            assert_eq!(r.next(), None);
            assert!(r.malformed, "{bad:?}");
        }
    }

    #[test]
    fn sealed_frames_open_and_any_changed_byte_is_refused() {
        let key = DirectionKey::new(&[7; 32]);
        let mut out = Vec::new();
        key.seal(&mut out, (SystemId(1), SystemId(2)), 9, 3, b"head", b"body");
        assert_eq!(out.len(), OVERHEAD + 8);
        let p = prefix(&out).unwrap();
        assert_eq!(
            (p.kind, p.sender, p.receiver),
            (Kind::Data, SystemId(1), SystemId(2))
        );
        assert_eq!(data_counter(&out), 3);
        let mut good = out.clone();
        assert!(key.open(&mut good));
        assert_eq!(&good[DATA_HEADER_LEN..good.len() - TAG_LEN], b"headbody");
        let mut inner = vec![0; inner_len(out.len())];
        assert!(key.open_into(&out, &mut inner));
        assert_eq!(inner, b"headbody");
        // A reused, longer buffer gives the same frame.
        let mut reused = vec![9; 500];
        key.seal(
            &mut reused,
            (SystemId(1), SystemId(2)),
            9,
            3,
            b"head",
            b"body",
        );
        assert_eq!(reused, out);
        for i in 0..out.len() {
            let mut bad = out.clone();
            bad[i] ^= 1;
            assert!(
                !key.open(&mut bad.clone()),
                "byte {i} changed and still opened"
            );
            assert!(
                !key.open_into(&bad, &mut inner),
                "byte {i} changed and still opened"
            );
        }
        assert!(!DirectionKey::new(&[8; 32]).open(&mut out.clone()));
        assert!(!key.open(&mut out[..OVERHEAD - 1].to_vec()));
        assert!(!key.open_into(&out[..OVERHEAD - 1], &mut []));
        assert!(
            !key.open_into(&out, &mut [0; 3]),
            "an output of the wrong length"
        );
    }
}
