//! Shared helpers for frame-level tests: a simulated RS-485 line that feeds
//! bytes with timestamps through the frame assembler into a [`Device`],
//! exactly as the UART interrupt and the glue do (SPEC §1), and takes the
//! replies back.
//!
//! Timestamps mark the *end* of each character (src/rtu/assembler.rs), so
//! two back-to-back characters are one character time `tc` apart and a
//! silence of `s` µs between them puts them `tc + s` apart.
//!
//! ```ignore
//! mod common;
//! use common::*;
//! let mut bus = Bus::new();
//! assert_eq!(bus.send(&hex("01 06 60 83 00 64 67 C9")), Some(hex("01 06 60 83 00 64 67 C9")));
//! ```
#![allow(dead_code)] // each test binary uses a different part of it

use modbus_drive::device::{Device, Identity, Response};
use modbus_drive::rtu::{
    crc16, FrameAssembler, FrameTiming, LineConfig, RxEvent, RxFlags, MAX_FRAME,
};

/// Hardware string the test devices report in 0x1009.
pub const TEST_HARDWARE: &str = "test-bench";

/// Bytes from a hex string such as `"01 03 60 7A 00 02 FB D2"`.
pub fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).expect("hex byte"))
        .collect()
}

/// `bytes` with its CRC appended, low byte first.
pub fn with_crc(bytes: &[u8]) -> Vec<u8> {
    let crc = crc16(bytes);
    let mut v = bytes.to_vec();
    v.extend_from_slice(&crc.to_le_bytes());
    v
}

/// The frame `address pdu… CRC`.
pub fn frame(address: u8, pdu: &[u8]) -> Vec<u8> {
    let mut v = vec![address];
    v.extend_from_slice(pdu);
    with_crc(&v)
}

/// The exception reply `address function|0x80 code CRC`.
pub fn exception(address: u8, function: u8, code: u8) -> Vec<u8> {
    frame(address, &[function | 0x80, code])
}

/// A reply as it went out on the line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Sent {
    pub bytes: Vec<u8>,
    /// When its first character started, µs.
    pub start_us: u32,
    /// Timestamp of the request's last byte.
    pub request_end_us: u32,
    /// First byte (address) of the frame this reply answers; `None` for a
    /// deferred reply (an EE operation finishing, `poll_storage`).
    pub request_address: Option<u8>,
}

/// The address byte of a closed frame, if it is one.
fn frame_address(rx: &RxEvent<'_>) -> Option<u8> {
    match rx {
        RxEvent::Frame { bytes, .. } => bytes.first().copied(),
        _ => None,
    }
}

/// A device on a simulated line, with its frame assembler and a clock.
pub struct Bus {
    pub device: Device,
    assembler: FrameAssembler,
    timing: FrameTiming,
    /// Timestamp of the last event on the line (end of last character).
    now_us: u32,
    /// Every reply so far, oldest first.
    pub sent: Vec<Sent>,
}

impl Default for Bus {
    fn default() -> Self {
        Self::new()
    }
}

impl Bus {
    /// A fresh device at the default line (115200 8N1, address 1).
    pub fn new() -> Self {
        Self::with_device(Device::new(Identity::new(TEST_HARDWARE)))
    }

    /// A fresh device whose PA set is changed by `set` before the line
    /// starts (e.g. `|pa| pa.set_unchecked(52, 0)` for 9600 baud).
    pub fn with_params(set: impl FnOnce(&mut modbus_drive::params::Params)) -> Self {
        let mut device = Device::new(Identity::new(TEST_HARDWARE));
        device.configure(|pa, _| set(pa)); // the new address / line in force
        while device.take_event().is_some() {}
        Self::with_device(device)
    }

    pub fn with_device(device: Device) -> Self {
        let timing = device.line().timing();
        Self {
            device,
            assembler: FrameAssembler::new(timing),
            timing,
            // Start away from 0 so that wrap-around is not special here.
            now_us: 1_000_000,
            sent: Vec::new(),
        }
    }

    /// Timing of the line in force.
    pub fn timing(&self) -> FrameTiming {
        self.timing
    }

    pub fn now_us(&self) -> u32 {
        self.now_us
    }

    /// Sends `frame` back to back after a long silence, lets the line go
    /// quiet and returns the reply, if any. Panics on more than one reply.
    pub fn send(&mut self, frame: &[u8]) -> Option<Vec<u8>> {
        let before = self.sent.len();
        self.idle(10 * self.timing.t35_us());
        self.feed_gapped(frame.iter().map(|&b| (b, 0)));
        self.idle(10 * self.timing.t35_us());
        assert!(self.sent.len() <= before + 1, "more than one reply");
        self.sent.get(before).map(|s| s.bytes.clone())
    }

    /// `send` of `address pdu… CRC`.
    pub fn request(&mut self, address: u8, pdu: &[u8]) -> Option<Vec<u8>> {
        self.send(&frame(address, pdu))
    }

    /// Feeds bytes, each after its own silence in µs (0 = back to back),
    /// without closing the last frame. Returns the replies it caused.
    pub fn feed_gapped(&mut self, bytes: impl IntoIterator<Item = (u8, u32)>) -> Vec<Vec<u8>> {
        let before = self.sent.len();
        for (b, silence_us) in bytes {
            let at = self
                .now_us
                .wrapping_add(self.timing.tc_us())
                .wrapping_add(silence_us);
            self.push(b, at, RxFlags::NONE);
        }
        self.sent[before..]
            .iter()
            .map(|s| s.bytes.clone())
            .collect()
    }

    /// One byte ending at `at_us` with UART flags.
    pub fn push(&mut self, byte: u8, at_us: u32, flags: RxFlags) {
        let prev_end = self.assembler.last_byte_at_us();
        self.now_us = at_us;
        let mut reply = [0u8; MAX_FRAME];
        let response = match self.assembler.push(byte, at_us, flags) {
            Some(rx) => Some((frame_address(&rx), self.device.handle_rx(rx, &mut reply))),
            None => None,
        };
        if let Some((address, r)) = response {
            // The byte closed the previous frame: its reply would have
            // collided with this byte; tests that get here send frames
            // without waiting, like a master that does not wait.
            self.after(r, &reply, prev_end, false, address);
        }
    }

    /// Silence for `us`: polls the assembler the way a timer would (every
    /// 10 µs), handling the frame it closes and sending the reply.
    pub fn idle(&mut self, us: u32) {
        let start = self.now_us;
        let mut elapsed = 0;
        while elapsed < us {
            elapsed += 10.min(us - elapsed);
            let t = start.wrapping_add(elapsed);
            let last = self.assembler.last_byte_at_us();
            let mut reply = [0u8; MAX_FRAME];
            let response = match self.assembler.poll(t) {
                Some(rx) => Some((frame_address(&rx), self.device.handle_rx(rx, &mut reply))),
                None => None,
            };
            if let Some((address, r)) = response {
                self.now_us = t;
                self.after(r, &reply, last, true, address);
            }
        }
        let end = start.wrapping_add(us);
        if end.wrapping_sub(self.now_us) as i32 > 0 {
            self.now_us = end;
        }
    }

    /// Sends a reply no earlier than `reply_delay_us` after the request's
    /// last byte, in one burst, then tells the device it left. With
    /// `occupy_line` the clock moves past the reply (the master waited for
    /// it); without, the master's bytes keep their own timestamps.
    fn after(
        &mut self,
        response: Response,
        reply: &[u8; MAX_FRAME],
        request_end_us: u32,
        occupy_line: bool,
        request_address: Option<u8>,
    ) {
        if let Response::Reply(n) = response {
            let start_us = request_end_us.wrapping_add(self.device.reply_delay_us());
            self.sent.push(Sent {
                bytes: reply[..n].to_vec(),
                start_us,
                request_end_us,
                request_address,
            });
            if occupy_line {
                self.now_us = start_us.wrapping_add(n as u32 * self.timing.tc_us());
            }
        }
        if let Some(line) = self.device.reply_sent() {
            self.set_line(line);
        }
    }

    /// The glue's storage step (`Device::poll_storage`): runs a waiting EE operation on
    /// `store` and sends its deferred reply like any other; returns it.
    pub fn poll_storage<F: embedded_storage::nor_flash::NorFlash>(
        &mut self,
        store: &mut modbus_drive::params::ParamStore<F>,
    ) -> Option<Vec<u8>> {
        let before = self.sent.len();
        let mut reply = [0u8; MAX_FRAME];
        let response = self.device.poll_storage(store, &mut reply)?;
        let request_end = self.assembler.last_byte_at_us();
        self.after(response, &reply, request_end, true, None);
        self.sent.get(before).map(|s| s.bytes.clone())
    }

    fn set_line(&mut self, line: LineConfig) {
        self.timing = line.timing();
        self.assembler.set_timing(self.timing);
    }

    /// Reads `quantity` registers from `start` at our address; the data
    /// words, or the exception code.
    pub fn read(&mut self, start: u16, quantity: u16) -> Result<Vec<u16>, u8> {
        let address = self.device.address();
        let mut pdu = vec![0x03];
        pdu.extend_from_slice(&start.to_be_bytes());
        pdu.extend_from_slice(&quantity.to_be_bytes());
        let reply = self.request(address, &pdu).expect("a reply");
        decode_read(&reply)
    }

    /// Writes `words` from `start` with 0x10; `Err(code)` on an exception.
    pub fn write(&mut self, start: u16, words: &[u16]) -> Result<(), u8> {
        let address = self.device.address();
        let reply = self
            .request(address, &write_pdu(start, words))
            .expect("a reply");
        match reply[1] {
            0x10 => Ok(()),
            _ => Err(reply[2]),
        }
    }

    /// Writes one register with 0x06; `Err(code)` on an exception.
    pub fn write_single(&mut self, address_reg: u16, value: u16) -> Result<(), u8> {
        let address = self.device.address();
        let mut pdu = vec![0x06];
        pdu.extend_from_slice(&address_reg.to_be_bytes());
        pdu.extend_from_slice(&value.to_be_bytes());
        let reply = self.request(address, &pdu).expect("a reply");
        match reply[1] {
            0x06 => Ok(()),
            _ => Err(reply[2]),
        }
    }

    /// Drains the device's events.
    pub fn events(&mut self) -> Vec<modbus_drive::event::Event> {
        std::iter::from_fn(|| self.device.take_event()).collect()
    }
}

/// The 0x10 PDU writing `words` from `start`.
pub fn write_pdu(start: u16, words: &[u16]) -> Vec<u8> {
    let mut pdu = vec![0x10];
    pdu.extend_from_slice(&start.to_be_bytes());
    pdu.extend_from_slice(&(words.len() as u16).to_be_bytes());
    pdu.push((2 * words.len()) as u8);
    for w in words {
        pdu.extend_from_slice(&w.to_be_bytes());
    }
    pdu
}

/// Data words of a 0x03 reply (CRC checked), or its exception code.
pub fn decode_read(reply: &[u8]) -> Result<Vec<u16>, u8> {
    assert_eq!(crc16(reply), 0, "reply CRC");
    if reply[1] & 0x80 != 0 {
        return Err(reply[2]);
    }
    assert_eq!(reply[1], 0x03);
    assert_eq!(usize::from(reply[2]), reply.len() - 5);
    Ok(reply[3..reply.len() - 2]
        .chunks(2)
        .map(|c| u16::from_be_bytes([c[0], c[1]]))
        .collect())
}

/// Motion harness: planner / device on a simulated axis.
pub mod axis;
