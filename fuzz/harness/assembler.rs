//! Frame assembler fed bytes with random gaps, flags, polls and wrapping
//! timestamps (SPEC §1), checked event by event against a reference model
//! that restates the SPEC rules directly.
//!
//! Input: line selection, start time, then 2-byte operations `op value`:
//! `op & 3` = 0/1 push `value` after a gap of class `(op >> 2) & 15`
//! (flags when bit 7 is set: bit 6 and `value` choose which), 2 poll after
//! such a gap, 3 end of frame (receiver timeout).

use super::Input;
use modbus_drive::rtu::{
    CharFormat, FrameAssembler, FrameTiming, LineConfig, RxEvent, RxFlags, MAX_FRAME, MIN_FRAME,
};

/// What the assembler must report, owned.
#[derive(Debug, PartialEq, Eq)]
enum Expected {
    Frame(Vec<u8>, bool),
    Broken,
    TooShort,
    Overrun,
}

fn owned(ev: RxEvent<'_>) -> Expected {
    match ev {
        RxEvent::Frame {
            bytes,
            parity_error,
        } => Expected::Frame(bytes.to_vec(), parity_error),
        RxEvent::Broken => Expected::Broken,
        RxEvent::TooShort => Expected::TooShort,
        RxEvent::Overrun => Expected::Overrun,
    }
}

/// SPEC §1 as written: silence = Δt − tc between end-of-character stamps;
/// silence above t1.5 breaks the frame, at least t3.5 ends it; fewer than
/// 4 bytes are dropped, more than 256 (or a UART overrun) are an overrun;
/// parity is carried; a framing error breaks. Wide signed arithmetic.
struct Model {
    timing: FrameTiming,
    open: bool,
    bytes: Vec<u8>,
    last_us: u32,
    broken: bool,
    parity: bool,
    overrun: bool,
}

impl Model {
    fn silence_us(&self, now_us: u32) -> i64 {
        i64::from(now_us.wrapping_sub(self.last_us)) - i64::from(self.timing.tc_us())
    }

    fn close(&mut self) -> Expected {
        self.open = false;
        let bytes = std::mem::take(&mut self.bytes);
        if self.overrun || bytes.len() > MAX_FRAME {
            Expected::Overrun
        } else if self.broken {
            Expected::Broken
        } else if bytes.len() < MIN_FRAME {
            Expected::TooShort
        } else {
            Expected::Frame(bytes, self.parity)
        }
    }

    fn push(&mut self, byte: u8, at_us: u32, flags: RxFlags) -> Option<Expected> {
        let mut closed = None;
        if self.open {
            let silence = self.silence_us(at_us);
            if silence >= i64::from(self.timing.t35_us()) {
                closed = Some(self.close());
            } else if silence > i64::from(self.timing.t15_us()) {
                self.broken = true;
            }
        }
        if !self.open {
            *self = Model {
                timing: self.timing,
                open: true,
                bytes: Vec::new(),
                last_us: at_us,
                broken: false,
                parity: false,
                overrun: false,
            };
        }
        self.bytes.push(byte);
        self.last_us = at_us;
        self.parity |= flags.parity();
        self.broken |= flags.framing();
        self.overrun |= flags.overrun();
        closed
    }

    fn poll(&mut self, now_us: u32) -> Option<Expected> {
        // poll measures from the end of the last character: silence is Δt
        let since_last = i64::from(now_us.wrapping_sub(self.last_us));
        (self.open && since_last >= i64::from(self.timing.t35_us())).then(|| self.close())
    }
}

fn line(sel: u8) -> LineConfig {
    let baud = [9600, 19_200, 38_400, 57_600, 115_200][usize::from(sel % 5)];
    let format = CharFormat::from_pa53(u16::from(sel / 5 % 4)).unwrap_or(CharFormat::N1);
    LineConfig::new(baud, format)
}

/// The gap before an operation: around every threshold, and wild ones.
fn gap_us(class: u8, value: u8, t: FrameTiming) -> u32 {
    let (tc, t15, t35) = (t.tc_us(), t.t15_us(), t.t35_us());
    match class {
        0..=3 => tc,
        4 => tc + t15,
        5 => tc + t15 + 1,
        6 => tc + t35 - 1,
        7 => tc + t35,
        8 => tc + t35 + 1,
        9 => 0,
        10 => tc - 1,
        11 => 2 * tc + u32::from(value),
        12 => t35 - 1,
        13 => t35,
        14 => u32::from(value) * 97,
        _ => u32::MAX - u32::from(value), // a timestamp that went backwards
    }
}

pub fn run(data: &[u8]) {
    let mut input = Input::new(data);
    let timing = line(input.u8()).timing();
    let mut now_us = input.u32();
    let mut assembler = FrameAssembler::new(timing);
    let mut model = Model {
        timing,
        open: false,
        bytes: Vec::new(),
        last_us: 0,
        broken: false,
        parity: false,
        overrun: false,
    };
    while !input.is_empty() {
        let op = input.u8();
        let value = input.u8();
        now_us = now_us.wrapping_add(gap_us((op >> 2) & 15, value, timing));
        let (got, want) = match op & 3 {
            0 | 1 => {
                let flags = if op & 0x80 == 0 {
                    RxFlags::NONE
                } else {
                    RxFlags::new(op & 0x40 != 0, value & 1 != 0, value & 2 != 0)
                };
                (
                    assembler.push(value, now_us, flags).map(owned),
                    model.push(value, now_us, flags),
                )
            }
            2 => (assembler.poll(now_us).map(owned), model.poll(now_us)),
            _ => (
                assembler.end_of_frame().map(owned),
                model.open.then(|| model.close()),
            ),
        };
        assert_eq!(got, want, "event at t = {now_us} µs");
        assert_eq!(assembler.is_receiving(), model.open);
        if let Some(Expected::Frame(bytes, _)) = &got {
            assert!((MIN_FRAME..=MAX_FRAME).contains(&bytes.len()));
        }
    }
}
