//! Modbus TCP framing: the MBAP header of the "MODBUS Messaging on TCP/IP
//! Implementation Guide V1.0b" (§3.1.3) around a PDU. Sans-IO and heap-free
//! like the rest of the core, so any glue with a TCP stack can use it (the
//! virtual drive today; a firmware-in-the-loop runner or a board with an
//! Ethernet controller later).
//!
//! ```text
//! transaction (2) | protocol = 0 (2) | length (2) | unit (1) | PDU (1..=253)
//! ```
//! All fields big-endian; `length` counts the unit byte and the PDU, so a
//! valid request has `2..=254`.
//!
//! [`Decoder`] cuts a TCP byte stream into requests with one fixed buffer
//! of [`MAX_ADU`] bytes, whatever the peer sends. What the guide says about
//! bad headers, and what the decoder reports:
//! - protocol identifier not 0 (another protocol multiplexed on the
//!   stream): the ADU is skipped and discarded without a reply
//!   ([`Frame::ForeignProtocol`]); the stream stays in step because the
//!   length field still delimits it;
//! - length outside `2..=254`: the ADU boundary is lost, so nothing after
//!   it can be trusted: [`Frame::BadLength`], and the glue closes the
//!   connection.

/// The MBAP header's size.
pub const HEADER_LEN: usize = 7;
/// Largest PDU (function code and data), as on the serial line.
pub const MAX_PDU: usize = 253;
/// Largest Modbus TCP ADU: header and PDU.
pub const MAX_ADU: usize = HEADER_LEN + MAX_PDU;
/// The protocol identifier of Modbus.
pub const PROTOCOL_MODBUS: u16 = 0;
/// Smallest valid `length`: the unit byte and a function code.
pub const MIN_LENGTH: u16 = 2;
/// Largest valid `length`: the unit byte and a full PDU.
pub const MAX_LENGTH: u16 = 1 + MAX_PDU as u16;
/// The unit identifier a client uses for "the server at this IP address"
/// (guide §3.1.3, the recommended non-significant value; 0 is accepted
/// for it too).
pub const UNIT_SERVER: u8 = 0xFF;

/// Exception codes only a gateway sends (Modbus Application Protocol
/// V1.1b3 §7): no path to the unit, or the unit did not answer.
pub const EXCEPTION_GATEWAY_PATH_UNAVAILABLE: u8 = 0x0A;
pub const EXCEPTION_GATEWAY_TARGET_FAILED: u8 = 0x0B;

/// An MBAP header as received.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    transaction: u16,
    protocol: u16,
    length: u16,
    unit: u8,
}

impl Header {
    /// The fields of the first [`HEADER_LEN`] bytes of `b`.
    pub fn parse(b: &[u8; HEADER_LEN]) -> Self {
        Self {
            transaction: u16::from_be_bytes([b[0], b[1]]),
            protocol: u16::from_be_bytes([b[2], b[3]]),
            length: u16::from_be_bytes([b[4], b[5]]),
            unit: b[6],
        }
    }

    pub fn transaction(&self) -> u16 {
        self.transaction
    }

    pub fn protocol(&self) -> u16 {
        self.protocol
    }

    /// The length field: unit byte plus PDU.
    pub fn length(&self) -> u16 {
        self.length
    }

    pub fn unit(&self) -> u8 {
        self.unit
    }

    fn length_valid(&self) -> bool {
        (MIN_LENGTH..=MAX_LENGTH).contains(&self.length)
    }
}

/// What [`Decoder::feed`] found once an ADU is complete (or hopeless).
#[derive(Debug, PartialEq, Eq)]
pub enum Frame<'a> {
    /// A Modbus request: answer it with [`encode_response`].
    Request { header: Header, pdu: &'a [u8] },
    /// Protocol identifier not 0: discarded, no reply; the stream goes on.
    ForeignProtocol(Header),
    /// Length field outside `2..=254`: the stream cannot be delimited any
    /// more; close the connection. The decoder refuses further input.
    BadLength(Header),
}

/// Cuts a byte stream into MBAP ADUs with a fixed buffer (module docs).
#[derive(Clone, Debug)]
pub struct Decoder {
    buf: [u8; MAX_ADU],
    len: usize,
    /// The last call returned a complete ADU: start afresh on the next one.
    done: bool,
    /// A bad length was seen; nothing more is decoded.
    broken: bool,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_ADU],
            len: 0,
            done: false,
            broken: false,
        }
    }

    /// Bytes of an ADU begun and not finished (a peer that closes now has
    /// sent a truncated request).
    pub fn pending(&self) -> usize {
        if self.done {
            0
        } else {
            self.len
        }
    }

    /// Takes bytes from `input` up to the end of the current ADU. Returns
    /// how many it took and, when the ADU is complete (or its header bad),
    /// what it is; call again with the rest of `input`. Never takes more
    /// than one ADU, never buffers more than [`MAX_ADU`] bytes.
    pub fn feed(&mut self, input: &[u8]) -> (usize, Option<Frame<'_>>) {
        if self.broken {
            return (0, None);
        }
        if self.done {
            self.len = 0;
            self.done = false;
        }
        let mut used = 0;
        if self.len < HEADER_LEN {
            used = self.take(input, HEADER_LEN);
            if self.len < HEADER_LEN {
                return (used, None);
            }
        }
        let mut head = [0u8; HEADER_LEN];
        head.copy_from_slice(&self.buf[..HEADER_LEN]);
        let header = Header::parse(&head);
        if !header.length_valid() {
            self.broken = true;
            self.done = true;
            return (used, Some(Frame::BadLength(header)));
        }
        // length counts the unit byte, which is the header's last byte
        let total = HEADER_LEN - 1 + usize::from(header.length);
        used += self.take(&input[used..], total);
        if self.len < total {
            return (used, None);
        }
        self.done = true;
        let frame = if header.protocol != PROTOCOL_MODBUS {
            Frame::ForeignProtocol(header)
        } else {
            Frame::Request {
                header,
                pdu: &self.buf[HEADER_LEN..total],
            }
        };
        (used, Some(frame))
    }

    /// Copies from `input` until the buffer holds `upto` bytes.
    fn take(&mut self, input: &[u8], upto: usize) -> usize {
        let n = upto.saturating_sub(self.len).min(input.len());
        self.buf[self.len..self.len + n].copy_from_slice(&input[..n]);
        self.len += n;
        n
    }
}

/// The response ADU to `request` carrying `pdu` (transaction and unit
/// copied from the request, protocol 0) into `out`; returns its length.
/// `pdu` longer than [`MAX_PDU`] is cut (the core never makes one).
pub fn encode_response(request: &Header, pdu: &[u8], out: &mut [u8; MAX_ADU]) -> usize {
    let pdu = &pdu[..pdu.len().min(MAX_PDU)];
    let length = (pdu.len() + 1) as u16;
    out[0..2].copy_from_slice(&request.transaction.to_be_bytes());
    out[2..4].copy_from_slice(&PROTOCOL_MODBUS.to_be_bytes());
    out[4..6].copy_from_slice(&length.to_be_bytes());
    out[6] = request.unit;
    out[HEADER_LEN..HEADER_LEN + pdu.len()].copy_from_slice(pdu);
    HEADER_LEN + pdu.len()
}

/// An exception PDU: the request's function code with bit 7 set, and
/// `code`.
pub fn exception_pdu(function: u8, code: u8) -> [u8; 2] {
    [function | 0x80, code]
}

#[cfg(test)]
mod tests {
    use super::*;

    const READ_SW: [u8; 12] = [
        0x12, 0x34, 0x00, 0x00, 0x00, 0x06, 0x01, 0x03, 0x60, 0x41, 0x00, 0x01,
    ];

    fn one(dec: &mut Decoder, bytes: &[u8]) -> (usize, Option<Frame<'static>>) {
        // Frames borrow the decoder; tests copy what they check.
        let (n, f) = dec.feed(bytes);
        let f = f.map(|f| match f {
            Frame::Request { header, pdu } => Frame::Request {
                header,
                pdu: Vec::leak(pdu.to_vec()),
            },
            Frame::ForeignProtocol(h) => Frame::ForeignProtocol(h),
            Frame::BadLength(h) => Frame::BadLength(h),
        });
        (n, f)
    }

    #[test]
    fn a_whole_request_is_cut_with_its_header_fields() {
        let mut d = Decoder::new();
        let (n, f) = one(&mut d, &READ_SW);
        assert_eq!(n, 12);
        let Some(Frame::Request { header, pdu }) = f else {
            panic!("{f:?}")
        };
        assert_eq!(header.transaction(), 0x1234);
        assert_eq!(header.protocol(), 0);
        assert_eq!(header.length(), 6);
        assert_eq!(header.unit(), 1);
        assert_eq!(pdu, &[0x03, 0x60, 0x41, 0x00, 0x01]);
        assert_eq!(d.pending(), 0);
    }

    #[test]
    fn a_request_split_anywhere_and_two_back_to_back_decode_the_same() {
        for cut in 0..=READ_SW.len() {
            let mut d = Decoder::new();
            let (n, f) = one(&mut d, &READ_SW[..cut]);
            assert_eq!(n, cut);
            if cut < READ_SW.len() {
                assert_eq!(f, None, "cut {cut}");
                assert_eq!(d.pending(), cut);
                let (m, f) = one(&mut d, &READ_SW[cut..]);
                assert_eq!(m, READ_SW.len() - cut);
                assert!(matches!(f, Some(Frame::Request { .. })), "cut {cut}");
            } else {
                assert!(matches!(f, Some(Frame::Request { .. })));
            }
        }
        // pipelined: the decoder takes exactly one ADU per call
        let mut two = READ_SW.to_vec();
        two.extend_from_slice(&READ_SW);
        two[12 + 1] = 0x35;
        let mut d = Decoder::new();
        let (n, f) = one(&mut d, &two);
        assert_eq!(n, 12);
        assert!(matches!(f, Some(Frame::Request { header, .. }) if header.transaction() == 0x1234));
        let (m, f) = one(&mut d, &two[n..]);
        assert_eq!(m, 12);
        assert!(matches!(f, Some(Frame::Request { header, .. }) if header.transaction() == 0x1235));
    }

    #[test]
    fn a_foreign_protocol_is_skipped_whole_and_the_stream_goes_on() {
        let mut bytes = READ_SW.to_vec();
        bytes[3] = 0x01; // protocol 1
        bytes.extend_from_slice(&READ_SW);
        let mut d = Decoder::new();
        let (n, f) = one(&mut d, &bytes);
        assert_eq!(n, 12);
        assert!(matches!(f, Some(Frame::ForeignProtocol(h)) if h.protocol() == 1));
        let (_, f) = one(&mut d, &bytes[n..]);
        assert!(matches!(f, Some(Frame::Request { .. })));
    }

    #[test]
    fn lengths_outside_2_to_254_break_the_stream_for_good() {
        for bad in [0u16, 1, 255, 256, 0xFFFF] {
            let mut bytes = READ_SW.to_vec();
            bytes[4..6].copy_from_slice(&bad.to_be_bytes());
            let mut d = Decoder::new();
            let (n, f) = one(&mut d, &bytes);
            assert_eq!(n, HEADER_LEN, "length {bad}: only the header is taken");
            assert!(
                matches!(f, Some(Frame::BadLength(h)) if h.length() == bad),
                "{bad}"
            );
            assert_eq!(one(&mut d, &READ_SW), (0, None), "refuses more after {bad}");
        }
        for good in [MIN_LENGTH, MAX_LENGTH] {
            let mut bytes = READ_SW[..HEADER_LEN].to_vec();
            bytes[4..6].copy_from_slice(&good.to_be_bytes());
            bytes.resize(HEADER_LEN - 1 + usize::from(good), 0x03);
            let mut d = Decoder::new();
            let (n, f) = one(&mut d, &bytes);
            assert_eq!(n, bytes.len());
            let Some(Frame::Request { pdu, .. }) = f else {
                panic!("{good}: {f:?}")
            };
            assert_eq!(pdu.len(), usize::from(good) - 1);
        }
    }

    #[test]
    fn responses_copy_transaction_and_unit_and_count_their_length() {
        let mut d = Decoder::new();
        let mut req = READ_SW;
        req[6] = 0xFF;
        let (_, f) = d.feed(&req);
        let Some(Frame::Request { header, .. }) = f else {
            panic!()
        };
        let mut out = [0u8; MAX_ADU];
        let n = encode_response(&header, &[0x03, 0x02, 0x02, 0x37], &mut out);
        assert_eq!(
            &out[..n],
            &[0x12, 0x34, 0x00, 0x00, 0x00, 0x05, 0xFF, 0x03, 0x02, 0x02, 0x37]
        );
        let n = encode_response(
            &header,
            &exception_pdu(0x03, EXCEPTION_GATEWAY_TARGET_FAILED),
            &mut out,
        );
        assert_eq!(
            &out[..n],
            &[0x12, 0x34, 0x00, 0x00, 0x00, 0x03, 0xFF, 0x83, 0x0B]
        );
    }

    #[test]
    fn any_byte_stream_keeps_the_buffer_bounded_and_never_panics() {
        // A cheap deterministic fuzz: pseudo-random chunks of bytes.
        let mut x: u32 = 0x1234_5678;
        let mut rnd = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        for _ in 0..200 {
            let mut d = Decoder::new();
            for _ in 0..50 {
                let len = (rnd() % 600) as usize;
                let chunk: Vec<u8> = (0..len).map(|_| rnd() as u8).collect();
                let mut off = 0;
                loop {
                    let (n, f) = d.feed(&chunk[off..]);
                    off += n;
                    if let Some(Frame::Request { pdu, .. }) = f {
                        assert!((1..=MAX_PDU).contains(&pdu.len()));
                    }
                    assert!(d.pending() <= MAX_ADU);
                    if n == 0 {
                        break;
                    }
                }
            }
        }
    }
}
