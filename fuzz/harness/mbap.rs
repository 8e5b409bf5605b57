//! Modbus TCP framing (`modbus_drive::mbap`): any byte stream, cut into
//! any chunks, decodes to exactly what a reference parser restating the
//! MBAP rules finds in the whole stream, with at most one ADU buffered;
//! and every request's response decodes back to the request's transaction
//! and unit.
//!
//! Input: `n` (chunk sizes to cycle: 1 + n % 8), that many sizes (0 counts
//! as 1), then the stream.

use super::Input;
use modbus_drive::mbap::{encode_response, Decoder, Frame, HEADER_LEN, MAX_ADU};

/// What the decoder must report, owned: (transaction, protocol, length,
/// unit) and the PDU of a request.
#[derive(Debug, PartialEq, Eq)]
enum Expected {
    Request([u16; 3], u8, Vec<u8>),
    Foreign([u16; 3], u8),
    BadLength([u16; 3], u8),
}

/// The guide's rules on the whole stream: 7-byte header, big-endian;
/// length outside 2..=254 ends decoding; an ADU is 6 + length bytes;
/// protocol not 0 is skipped. Returns the ADUs and the bytes of an
/// unfinished one at the end.
fn model(stream: &[u8]) -> (Vec<Expected>, usize) {
    let mut out = Vec::new();
    let mut at = 0;
    loop {
        let rest = &stream[at..];
        if rest.len() < 7 {
            return (out, rest.len());
        }
        let be = |i: usize| u16::from_be_bytes([rest[i], rest[i + 1]]);
        let fields = [be(0), be(2), be(4)];
        let unit = rest[6];
        let length = usize::from(fields[2]);
        if !(2..=254).contains(&length) {
            out.push(Expected::BadLength(fields, unit));
            return (out, 0);
        }
        let total = 6 + length;
        if rest.len() < total {
            return (out, rest.len());
        }
        out.push(if fields[1] != 0 {
            Expected::Foreign(fields, unit)
        } else {
            Expected::Request(fields, unit, rest[7..total].to_vec())
        });
        at += total;
    }
}

fn owned(f: Frame<'_>) -> Expected {
    let key = |h: &modbus_drive::mbap::Header| [h.transaction(), h.protocol(), h.length()];
    match f {
        Frame::Request { header, pdu } => {
            Expected::Request(key(&header), header.unit(), pdu.to_vec())
        }
        Frame::ForeignProtocol(h) => Expected::Foreign(key(&h), h.unit()),
        Frame::BadLength(h) => Expected::BadLength(key(&h), h.unit()),
    }
}

pub fn run(data: &[u8]) {
    let mut input = Input::new(data);
    let n = 1 + usize::from(input.u8() % 8);
    let sizes: Vec<usize> = input
        .bytes(n)
        .iter()
        .map(|&s| usize::from(s).max(1))
        .collect();
    let sizes = if sizes.is_empty() { vec![1] } else { sizes };
    let stream = input.bytes(usize::MAX);
    let (expected, unfinished) = model(stream);

    let mut dec = Decoder::new();
    let mut got = Vec::new();
    let mut at = 0;
    let mut broken = false;
    'chunks: for size in sizes.iter().cycle() {
        if at >= stream.len() {
            break;
        }
        let chunk = &stream[at..(at + size).min(stream.len())];
        let mut off = 0;
        while off < chunk.len() {
            let (used, frame) = dec.feed(&chunk[off..]);
            let frame = frame.map(owned);
            assert!(used <= chunk.len() - off);
            assert!(dec.pending() <= MAX_ADU);
            let bad = matches!(frame, Some(Expected::BadLength(..)));
            // only a broken decoder takes nothing from a non-empty slice,
            // and it broke on the BadLength reported just now
            assert!(used > 0 || frame.is_some(), "took nothing, not broken");
            got.extend(frame);
            off += used;
            if bad {
                broken = true;
                break 'chunks;
            }
        }
        at += chunk.len();
    }
    assert_eq!(got, expected, "chunked as {sizes:?}");
    if broken {
        // refuses everything after a bad length
        assert_eq!(dec.feed(stream).0, 0);
        assert!(matches!(expected.last(), Some(Expected::BadLength(..))));
    } else {
        assert_eq!(dec.pending(), unfinished);
    }

    // responses: transaction and unit echoed, protocol 0, own length
    for e in &expected {
        let Expected::Request(fields, unit, pdu) = e else {
            continue;
        };
        let mut req = [0u8; HEADER_LEN];
        req[0..2].copy_from_slice(&fields[0].to_be_bytes());
        req[4..6].copy_from_slice(&fields[2].to_be_bytes());
        req[6] = *unit;
        let header = modbus_drive::mbap::Header::parse(&req);
        let mut out = [0u8; MAX_ADU];
        let len = encode_response(&header, pdu, &mut out);
        assert_eq!(len, HEADER_LEN + pdu.len());
        let mut back = Decoder::new();
        let (used, f) = back.feed(&out[..len]);
        assert_eq!(used, len);
        let want = [fields[0], 0, (pdu.len() + 1) as u16];
        assert_eq!(
            f.map(owned),
            Some(Expected::Request(want, *unit, pdu.clone()))
        );
    }
}
