//! Samples as raw CDR bodies: the bridge encodes and decodes message bodies itself, from a
//! schema chosen at run time ([`crate::rostypes`]), so rustdds only carries the bytes.

use rustdds::no_key::{Decode, DefaultDecoder, DeserializerAdapter, SerializerAdapter};
use rustdds::RepresentationIdentifier;

/// One sample's body (after the 4-byte encapsulation header) and how it is encoded.
#[derive(Clone, Debug, PartialEq)]
pub struct RawCdr {
    /// The body.
    pub body: Vec<u8>,
    /// Little endian (`CDR_LE`, `CDR2_LE`), else big endian.
    pub little: bool,
    /// XCDR version 2 (`CDR2_*`): 8-byte values are aligned to 4, not 8.
    pub xcdr2: bool,
}

/// The rustdds adapter for [`RawCdr`]: writes `CDR_LE` (what ROS 2 writes), reads plain CDR
/// and XCDR2 in either byte order.
pub struct RawAdapter;

/// Why a sample was refused before decoding (an encoding the bridge does not read).
#[derive(Debug, thiserror::Error)]
#[error("unsupported encoding {0:?}")]
pub struct RawError(RepresentationIdentifier);

const READS: [RepresentationIdentifier; 4] = [
    RepresentationIdentifier::CDR_LE,
    RepresentationIdentifier::CDR_BE,
    RepresentationIdentifier::CDR2_LE,
    RepresentationIdentifier::CDR2_BE,
];

impl SerializerAdapter<RawCdr> for RawAdapter {
    type Error = RawError;

    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }

    fn to_bytes(value: &RawCdr) -> Result<rustdds::bytes::Bytes, RawError> {
        Ok(rustdds::bytes::Bytes::from(value.body.clone()))
    }
}

impl DeserializerAdapter<RawCdr> for RawAdapter {
    type Error = RawError;
    type Decoded = RawCdr;

    fn supported_encodings() -> &'static [RepresentationIdentifier] {
        &READS
    }

    fn transform_decoded(decoded: RawCdr) -> RawCdr {
        decoded
    }
}

/// The decoder of [`RawAdapter`]: copies the body, notes the encoding.
#[derive(Clone)]
pub struct RawDecoder;

impl<'de> Decode<'de, RawCdr> for RawDecoder {
    type Error = RawError;

    fn decode_bytes(
        self,
        input_bytes: &'de [u8],
        encoding: RepresentationIdentifier,
    ) -> Result<RawCdr, RawError> {
        let (little, xcdr2) = match encoding {
            e if e == RepresentationIdentifier::CDR_LE => (true, false),
            e if e == RepresentationIdentifier::CDR_BE => (false, false),
            e if e == RepresentationIdentifier::CDR2_LE => (true, true),
            e if e == RepresentationIdentifier::CDR2_BE => (false, true),
            other => return Err(RawError(other)),
        };
        Ok(RawCdr {
            body: input_bytes.to_vec(),
            little,
            xcdr2,
        })
    }
}

impl DefaultDecoder<RawCdr> for RawAdapter {
    type Decoder = RawDecoder;
    const DECODER: RawDecoder = RawDecoder;
}
