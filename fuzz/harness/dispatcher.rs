//! The dispatcher fed whole frames (SPEC §2, §3, §5): a valid CRC is added
//! to half of them so that the fuzzer gets past the CRC check.
//!
//! Input: a configuration byte (PA54, PA55, word order, own address), then
//! frames `h1 h2 body…`: `h1 & 0x3F` body bytes (`h1 & 0x40`: one more
//! length byte adds up to 255), `h1 & 0x80` appends the right CRC; `h2`
//! bit 0 flags a UART parity error, bit 1 sets the address to ours, bit 2
//! to broadcast, bit 3 puts a supported function code (bits 4..6) second.
//!
//! Checks after every frame: no reply to a foreign or broadcast address;
//! every reply carries a valid CRC, our address and the request's function
//! (| 0x80 for exceptions, then 5 bytes); a refused request (exception
//! reply or exception event) changed no value, parameter, address, line or
//! drive state; the statusword encodes a valid state (§8.1).

use super::Input;
use modbus_drive::device::{Identity, Response};
use modbus_drive::dictionary::DriveLayer;
use modbus_drive::event::Event;
use modbus_drive::rtu::{crc16, LineConfig, RxEvent, MAX_FRAME};
use modbus_drive::Device;

const FUNCTIONS: [u8; 8] = [0x03, 0x06, 0x10, 0x08, 0x2B, 0x03, 0x06, 0x10];

/// Everything a refused request must leave alone.
#[derive(Debug, PartialEq)]
struct Snapshot {
    od: modbus_drive::dictionary::OdValues,
    pa: modbus_drive::params::Params,
    address: u8,
    line: LineConfig,
    statusword: u16,
    mode_display: i16,
    position: i32,
    error_register: u16,
}

fn snapshot(d: &Device) -> Snapshot {
    Snapshot {
        od: d.od().clone(),
        pa: d.params().clone(),
        address: d.address(),
        line: d.line(),
        statusword: d.drive().statusword(),
        mode_display: d.drive().mode_display(),
        position: d.drive().actual_position(),
        error_register: d.drive().error_register(),
    }
}

/// SPEC §8.1: bits 0–3, 5, 6 of the statusword name exactly one state.
pub fn statusword_is_a_state(sw: u16) -> bool {
    let low = sw & 0x6F;
    matches!(
        sw & 0x4F,
        0x00 // not ready to switch on   x0xx 0000
        | 0x40 // switch on disabled     x1xx 0000
        | 0x0F // fault reaction active  x0xx 1111
        | 0x08 // fault                  x0xx 1000
    ) || matches!(
        low,
        0x21 // ready to switch on       x01x 0001
        | 0x23 // switched on            x01x 0011
        | 0x27 // operation enabled      x01x 0111
        | 0x07 // quick stop active      x00x 0111
    )
}

fn configure(device: &mut Device, cfg: u8, address_byte: u8) {
    // PA54 answer frame errors, PA55 exception profile (§3, §5.2)
    let address = match cfg >> 3 & 3 {
        0 => 1,
        1 => 247,
        2 => 17,
        _ => address_byte.clamp(1, 247),
    };
    device.configure(|pa, od| {
        pa.set_answer_frame_errors(cfg & 1 != 0);
        pa.set_standard_exceptions(cfg >> 1 & 1 != 0);
        od.set_word_order(u16::from(cfg >> 2 & 1));
        pa.set_address(address);
    });
    assert_eq!(device.address(), address); // in force at once
}

/// One frame through `handle_rx` with every per-frame check (module docs).
pub fn check_frame(
    device: &mut Device,
    frame: &[u8],
    parity_error: bool,
    reply: &mut [u8; MAX_FRAME],
) {
    let own = device.address();
    let before = snapshot(device);
    let rx = if frame.len() > MAX_FRAME {
        RxEvent::Overrun // what the assembler makes of it
    } else if frame.len() < 4 {
        RxEvent::TooShort
    } else {
        RxEvent::Frame {
            bytes: frame,
            parity_error,
        }
    };
    let response = device.handle_rx(rx, reply);
    let mut refused = false;
    while let Some(event) = device.take_event() {
        if matches!(event, Event::Exception { .. }) {
            refused = true;
        }
    }

    let address = frame.first().copied();
    if let Response::Reply(n) = response {
        assert!(
            address == Some(own) && own != 0,
            "reply to address {address:?}, ours is {own}: {frame:02X?}"
        );
        assert!((5..=MAX_FRAME).contains(&n), "reply length {n}");
        let r = &reply[..n];
        assert_eq!(crc16(r), 0, "reply CRC: {r:02X?}");
        assert_eq!(r[0], own);
        assert_eq!(r[1] & 0x7F, frame[1] & 0x7F, "reply function: {r:02X?}");
        if r[1] & 0x80 != 0 {
            assert_eq!(n, 5, "exception reply: {r:02X?}");
            assert!((1..=11).contains(&r[2]), "exception code: {r:02X?}");
            refused = true;
        }
    }
    let after = snapshot(device);
    if refused || address.is_some_and(|a| a != own && a != 0) {
        assert_eq!(
            before, after,
            "refused or foreign frame changed state: {frame:02X?}"
        );
    }
    assert!(
        statusword_is_a_state(after.statusword),
        "statusword {:#06X}",
        after.statusword
    );
}

pub fn run(data: &[u8]) {
    let mut input = Input::new(data);
    let mut device = Device::new(Identity::new("fuzz"));
    let cfg = input.u8();
    configure(&mut device, cfg, input.u8());
    let mut reply = [0u8; MAX_FRAME];
    let mut frame = Vec::with_capacity(512);

    while !input.is_empty() {
        let h1 = input.u8();
        let h2 = input.u8();
        let mut len = usize::from(h1 & 0x3F);
        if h1 & 0x40 != 0 {
            len += usize::from(input.u8());
        }
        frame.clear();
        frame.extend_from_slice(input.bytes(len));
        let own = device.address();
        if let Some(a) = frame.first_mut() {
            if h2 & 2 != 0 {
                *a = own;
            } else if h2 & 4 != 0 {
                *a = 0;
            }
        }
        if h2 & 8 != 0 && frame.len() > 1 {
            frame[1] = FUNCTIONS[usize::from(h2 >> 4 & 7)];
        }
        if h1 & 0x80 != 0 {
            let crc = crc16(&frame);
            frame.extend_from_slice(&crc.to_le_bytes());
        }
        let parity_error = h2 & 1 != 0;
        check_frame(&mut device, &frame, parity_error, &mut reply);
        // the glue calls this after every frame (SPEC §7)
        device.reply_sent();
    }
}
