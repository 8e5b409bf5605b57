//! The request PDUs this slave serves (SPEC §4): function codes and
//! quantity limits.

/// Function codes (§4).
pub mod function {
    pub const READ_HOLDING_REGISTERS: u8 = 0x03;
    pub const WRITE_SINGLE_REGISTER: u8 = 0x06;
    pub const DIAGNOSTICS: u8 = 0x08;
    pub const WRITE_MULTIPLE_REGISTERS: u8 = 0x10;
    pub const ENCAPSULATED_INTERFACE: u8 = 0x2B;
}

/// Largest quantity of a 0x03 read (§4).
pub const MAX_READ_QUANTITY: u16 = 125;
/// Largest quantity of a 0x10 write (§4).
pub const MAX_WRITE_QUANTITY: u16 = 123;

use super::Exception;

/// The address and word that follow the function code of a 0x03 / 0x06 /
/// 0x10 PDU; `None` when the PDU is too short for them.
fn address_and_word(pdu: &[u8]) -> Option<(u16, u16)> {
    match pdu {
        [_, a0, a1, q0, q1, ..] => Some((
            u16::from_be_bytes([*a0, *a1]),
            u16::from_be_bytes([*q0, *q1]),
        )),
        _ => None,
    }
}

/// A 0x03 request, `03 start quantity`, checked once (SPEC §5.2 steps 1
/// and 3): its length is exact and 1 ≤ quantity ≤ [`MAX_READ_QUANTITY`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadRequest {
    start: u16,
    quantity: u16,
}

impl ReadRequest {
    /// Exception 8 for a wrong length, 3 for a quantity out of range.
    pub fn new_checked(pdu: &[u8]) -> Result<Self, Exception> {
        let (start, quantity) = address_and_word(pdu)
            .filter(|_| pdu.len() == 5)
            .ok_or(Exception::ByteCountMismatch)?;
        if quantity == 0 || quantity > MAX_READ_QUANTITY {
            return Err(Exception::IllegalDataValue);
        }
        Ok(Self { start, quantity })
    }

    pub fn start(self) -> u16 {
        self.start
    }

    /// Registers to read, 1..=125.
    pub fn quantity(self) -> u16 {
        self.quantity
    }
}

/// A 0x06 request, `06 address value`, of exact length.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WriteSingleRequest {
    address: u16,
    value: u16,
}

impl WriteSingleRequest {
    /// Exception 8 for a wrong length.
    pub fn new_checked(pdu: &[u8]) -> Result<Self, Exception> {
        let (address, value) = address_and_word(pdu)
            .filter(|_| pdu.len() == 5)
            .ok_or(Exception::ByteCountMismatch)?;
        Ok(Self { address, value })
    }

    pub fn address(self) -> u16 {
        self.address
    }

    pub fn value(self) -> u16 {
        self.value
    }
}

/// A 0x10 request, `10 start quantity bytecount words…`, checked once: the
/// byte count matches both the quantity and the data (else exception 8),
/// then 1 ≤ quantity ≤ [`MAX_WRITE_QUANTITY`] (else exception 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WriteMultipleRequest<'a> {
    start: u16,
    quantity: u16,
    data: &'a [u8],
}

impl<'a> WriteMultipleRequest<'a> {
    pub fn new_checked(pdu: &'a [u8]) -> Result<Self, Exception> {
        let (start, quantity) = address_and_word(pdu).ok_or(Exception::ByteCountMismatch)?;
        let data = pdu.get(6..).ok_or(Exception::ByteCountMismatch)?;
        let byte_count = usize::from(pdu[5]);
        if byte_count != 2 * usize::from(quantity) || byte_count != data.len() {
            return Err(Exception::ByteCountMismatch);
        }
        if quantity == 0 || quantity > MAX_WRITE_QUANTITY {
            return Err(Exception::IllegalDataValue);
        }
        Ok(Self {
            start,
            quantity,
            data,
        })
    }

    pub fn start(self) -> u16 {
        self.start
    }

    /// Registers to write, 1..=123.
    pub fn quantity(self) -> u16 {
        self.quantity
    }

    /// `2 × quantity` bytes, big-endian words.
    pub fn data(self) -> &'a [u8] {
        self.data
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn read_requests_are_checked_before_their_fields_are_used() {
        assert_eq!(
            ReadRequest::new_checked(&[0x03, 0x60, 0x41, 0x00, 0x01]),
            Ok(ReadRequest {
                start: 0x6041,
                quantity: 1
            })
        );
        let short = [0x03, 0x60, 0x41, 0x00];
        let long = [0x03, 0x60, 0x41, 0x00, 0x01, 0x00];
        for pdu in [&short[..], &long[..], &[0x03]] {
            assert_eq!(
                ReadRequest::new_checked(pdu),
                Err(Exception::ByteCountMismatch)
            );
        }
        for quantity in [0u16, MAX_READ_QUANTITY + 1, u16::MAX] {
            let [q0, q1] = quantity.to_be_bytes();
            assert_eq!(
                ReadRequest::new_checked(&[0x03, 0xFF, 0xFF, q0, q1]),
                Err(Exception::IllegalDataValue),
                "quantity {quantity}"
            );
        }
    }

    #[test]
    fn write_single_requests_have_an_exact_length() {
        let r = WriteSingleRequest::new_checked(&[0x06, 0x60, 0x40, 0x00, 0x0F]);
        assert_eq!(r.map(|r| (r.address(), r.value())), Ok((0x6040, 0x000F)));
        assert_eq!(
            WriteSingleRequest::new_checked(&[0x06, 0x60, 0x40, 0x00]),
            Err(Exception::ByteCountMismatch)
        );
    }

    #[test]
    fn write_multiple_requests_check_byte_count_then_quantity() {
        let ok = [0x10, 0x60, 0x81, 0x00, 0x01, 0x02, 0x12, 0x34];
        let r = WriteMultipleRequest::new_checked(&ok);
        assert_eq!(
            r.map(|r| (r.start(), r.quantity(), r.data())),
            Ok((0x6081, 1, &ok[6..]))
        );
        // byte count against the quantity, then against the data
        for pdu in [
            &[0x10, 0x60, 0x81, 0x00, 0x01, 0x04, 0x12, 0x34][..],
            &[0x10, 0x60, 0x81, 0x00, 0x01, 0x02, 0x12][..],
            &[0x10, 0x60, 0x81, 0x00, 0x01][..],
        ] {
            assert_eq!(
                WriteMultipleRequest::new_checked(pdu),
                Err(Exception::ByteCountMismatch)
            );
        }
        // quantity 0 with a consistent byte count of 0: exception 3, and no
        // `start + quantity - 1` is ever formed from it
        assert_eq!(
            WriteMultipleRequest::new_checked(&[0x10, 0xFF, 0xFF, 0x00, 0x00, 0x00]),
            Err(Exception::IllegalDataValue)
        );
        let mut big = [0u8; 6 + 2 * 124];
        big[..6].copy_from_slice(&[0x10, 0x00, 0x64, 0x00, 124, 248]);
        assert_eq!(
            WriteMultipleRequest::new_checked(&big),
            Err(Exception::IllegalDataValue)
        );
    }
}
