//! Frame assembly from time-stamped bytes (SPEC §1).
//!
//! The UART receive interrupt calls [`FrameAssembler::push`] with every byte
//! and the time its stop bit ended; the glue calls [`FrameAssembler::poll`]
//! (or the hardware receiver timeout does the same job) to close a frame
//! after t3.5 of silence. Timestamps are microseconds from any free-running
//! counter, wrapping at 2^32: only differences are used, so `poll` must run
//! at least once every 35 minutes while a frame is open.
//!
//! Silence between two characters is `Δt − tc` (timestamps mark the end of a
//! character). Silence `> t1.5` inside a frame breaks it; silence `≥ t3.5`
//! ends it. Two buffers alternate so that a completed frame stays readable
//! while the next one arrives.

use super::{FrameTiming, MAX_FRAME, MIN_FRAME};

/// UART error flags of one received byte.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RxFlags {
    /// Parity error (PE): carried with the frame, answered with code 9 (SPEC §3).
    parity: bool,
    /// Framing error or noise (FE/NE): the frame is discarded as broken.
    framing: bool,
    /// The UART lost bytes (ORE): the frame is discarded as an overrun.
    overrun: bool,
}

impl RxFlags {
    /// Parity error (PE): carried with the frame, answered with code 9 (SPEC §3).
    #[inline]
    pub const fn parity(&self) -> bool {
        self.parity
    }

    /// Framing error or noise (FE/NE): the frame is discarded as broken.
    #[inline]
    pub const fn framing(&self) -> bool {
        self.framing
    }

    /// The UART lost bytes (ORE): the frame is discarded as an overrun.
    #[inline]
    pub const fn overrun(&self) -> bool {
        self.overrun
    }
}

impl RxFlags {
    /// The flags the UART raised with one byte.
    #[inline]
    pub const fn new(parity: bool, framing: bool, overrun: bool) -> Self {
        Self {
            parity,
            framing,
            overrun,
        }
    }

    pub const NONE: Self = Self {
        parity: false,
        framing: false,
        overrun: false,
    };
}

/// What a closed frame turned out to be.
#[derive(Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RxEvent<'a> {
    /// A complete frame of 4..=256 bytes, CRC not yet checked. `parity_error`
    /// is set if any of its bytes had a UART parity error.
    Frame { bytes: &'a [u8], parity_error: bool },
    /// Silence > t1.5 inside the frame, or a framing error: discarded, a bus
    /// communication error (§6).
    Broken,
    /// Fewer than 4 bytes: dropped silently, a bus communication error (§6).
    TooShort,
    /// More than 256 bytes, or bytes lost by the UART: dropped, a character
    /// overrun (§6).
    Overrun,
}

#[derive(Clone, Copy)]
enum Closed {
    Frame {
        buf: usize,
        len: usize,
        parity: bool,
    },
    Broken,
    TooShort,
    Overrun,
}

/// Byte + timestamp in, frames out. Sans-IO; see the module docs.
pub struct FrameAssembler {
    bufs: [[u8; MAX_FRAME]; 2],
    cur: usize,
    /// Bytes of the open frame (keeps counting past `MAX_FRAME`).
    len: usize,
    last_at_us: u32,
    open: bool,
    broken: bool,
    parity: bool,
    overrun: bool,
    /// `t1.5 + tc`: timestamp difference above which the frame breaks.
    break_after_us: u32,
    /// `t3.5 + tc`: timestamp difference from which a byte starts a new frame.
    new_frame_after_us: u32,
    /// `t3.5`: silence after the last byte that closes the frame in `poll`.
    t35_us: u32,
}

impl FrameAssembler {
    // Inlined: the firmware builds it in place in its static, instead of
    // through a call that clears both buffers with a generic memclr.
    #[inline(always)]
    pub const fn new(timing: FrameTiming) -> Self {
        Self {
            bufs: [[0; MAX_FRAME]; 2],
            cur: 0,
            len: 0,
            last_at_us: 0,
            open: false,
            broken: false,
            parity: false,
            overrun: false,
            break_after_us: timing.t15_us() + timing.tc_us(),
            new_frame_after_us: timing.t35_us() + timing.tc_us(),
            t35_us: timing.t35_us(),
        }
    }

    /// New line timing (baud or format changed). Applies from the next frame;
    /// call it between frames.
    pub fn set_timing(&mut self, timing: FrameTiming) {
        self.break_after_us = timing.t15_us() + timing.tc_us();
        self.new_frame_after_us = timing.t35_us() + timing.tc_us();
        self.t35_us = timing.t35_us();
    }

    /// True while a frame is being received (bytes seen, t3.5 not yet over).
    pub fn is_receiving(&self) -> bool {
        self.open
    }

    /// Timestamp of the last byte received.
    pub fn last_byte_at_us(&self) -> u32 {
        self.last_at_us
    }

    /// One received byte, time-stamped at the end of its stop bit. Returns
    /// the previous frame if this byte proves it closed (silence ≥ t3.5 and
    /// `poll` was not called in between).
    pub fn push(&mut self, byte: u8, at_us: u32, flags: RxFlags) -> Option<RxEvent<'_>> {
        // Hot path, once per byte in the UART interrupt: an unflagged byte
        // that starts a frame, or continues the open one in time and with
        // room. It does what `push_slow` would do then, with no stack frame.
        if flags == RxFlags::NONE {
            if !self.open {
                self.start_frame();
                self.append(byte, at_us);
                return None;
            }
            if at_us.wrapping_sub(self.last_at_us) <= self.break_after_us && self.len < MAX_FRAME {
                self.append(byte, at_us);
                return None;
            }
        }
        self.push_slow(byte, at_us, flags)
    }

    #[inline(always)]
    fn start_frame(&mut self) {
        self.open = true;
        self.len = 0;
        self.broken = false;
        self.parity = false;
        self.overrun = false;
    }

    /// Stores a byte of the open frame; `len < MAX_FRAME`.
    #[inline(always)]
    fn append(&mut self, byte: u8, at_us: u32) {
        let len = self.len;
        // `& 1`: `cur` is 0 or 1; saying so spares a bounds check
        self.bufs[self.cur & 1][len] = byte;
        self.len = len + 1;
        self.last_at_us = at_us;
    }

    /// Every other byte: the first of a frame, a late one, a flagged one.
    #[inline(never)]
    fn push_slow(&mut self, byte: u8, at_us: u32, flags: RxFlags) -> Option<RxEvent<'_>> {
        let mut closed = None;
        if self.open {
            let dt = at_us.wrapping_sub(self.last_at_us);
            if dt >= self.new_frame_after_us {
                closed = Some(self.close());
            } else if dt > self.break_after_us {
                self.broken = true;
            }
        }
        if !self.open {
            self.start_frame();
        }
        if self.len < MAX_FRAME {
            self.append(byte, at_us);
        } else {
            self.overrun = true;
            self.len += 1;
            self.last_at_us = at_us;
        }
        if flags != RxFlags::NONE {
            self.parity |= flags.parity;
            self.broken |= flags.framing;
            self.overrun |= flags.overrun;
        }
        closed.map(|c| self.event(c))
    }

    /// Closes the open frame once `now_us` is at least t3.5 after its last
    /// byte. Call it from a timer or the receiver-timeout interrupt.
    pub fn poll(&mut self, now_us: u32) -> Option<RxEvent<'_>> {
        if self.open && now_us.wrapping_sub(self.last_at_us) >= self.t35_us {
            let c = self.close();
            Some(self.event(c))
        } else {
            None
        }
    }

    /// Closes the open frame now, whatever the time: for hardware that
    /// signals t3.5 itself (the STM32G4 receiver timeout).
    pub fn end_of_frame(&mut self) -> Option<RxEvent<'_>> {
        if self.open {
            let c = self.close();
            Some(self.event(c))
        } else {
            None
        }
    }

    fn close(&mut self) -> Closed {
        self.open = false;
        if self.overrun {
            Closed::Overrun
        } else if self.broken {
            Closed::Broken
        } else if self.len < MIN_FRAME {
            Closed::TooShort
        } else {
            let buf = self.cur;
            self.cur ^= 1;
            Closed::Frame {
                buf,
                len: self.len,
                parity: self.parity,
            }
        }
    }

    fn event(&self, c: Closed) -> RxEvent<'_> {
        match c {
            Closed::Frame { buf, len, parity } => RxEvent::Frame {
                bytes: &self.bufs[buf][..len],
                parity_error: parity,
            },
            Closed::Broken => RxEvent::Broken,
            Closed::TooShort => RxEvent::TooShort,
            Closed::Overrun => RxEvent::Overrun,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rtu::{CharFormat, LineConfig};

    const B9600: LineConfig = LineConfig::new(9600, CharFormat::N1);

    /// Feeds `bytes` back to back starting at `t0` (end of first char at
    /// `t0`), returns every event and the timestamp of the last byte.
    fn feed(a: &mut FrameAssembler, bytes: &[u8], t0: u32, tc: u32) -> (Vec<Vec<u8>>, u32) {
        let mut out = Vec::new();
        let mut t = t0;
        for (i, &b) in bytes.iter().enumerate() {
            t = t0.wrapping_add(i as u32 * tc);
            if let Some(RxEvent::Frame { bytes, .. }) = a.push(b, t, RxFlags::NONE) {
                out.push(bytes.to_vec());
            }
        }
        (out, t)
    }

    const REQ: [u8; 8] = [0x01, 0x03, 0x60, 0x7A, 0x00, 0x02, 0xFB, 0xD2];

    #[test]
    fn a_frame_closes_after_t35_of_silence_and_not_before() {
        let timing = B9600.timing();
        let mut a = FrameAssembler::new(timing);
        let (_, last) = feed(&mut a, &REQ, 1000, timing.tc_us());
        assert_eq!(a.poll(last + timing.t35_us() - 1), None);
        match a.poll(last + timing.t35_us()) {
            Some(RxEvent::Frame {
                bytes,
                parity_error,
            }) => {
                assert_eq!(bytes, REQ);
                assert!(!parity_error);
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(a.poll(last + 10 * timing.t35_us()), None);
    }

    #[test]
    fn silence_just_over_t15_breaks_the_frame_and_just_under_does_not() {
        for (baud, extra, broken) in [
            (9600, 0, false),
            (9600, 1, true),
            (115_200, 0, false),
            (115_200, 1, true),
        ] {
            let line = LineConfig::new(baud, CharFormat::N1);
            let timing = line.timing();
            let mut a = FrameAssembler::new(timing);
            let (_, t) = feed(&mut a, &REQ[..3], 0, timing.tc_us());
            // next byte ends one character time after silence t1.5 (+extra)
            let t = t + timing.t15_us() + extra + timing.tc_us();
            let (_, last) = feed(&mut a, &REQ[3..], t, timing.tc_us());
            let ev = a.poll(last + timing.t35_us());
            if broken {
                assert_eq!(ev, Some(RxEvent::Broken), "baud {baud}");
            } else {
                assert!(
                    matches!(ev, Some(RxEvent::Frame { .. })),
                    "baud {baud}: {ev:?}"
                );
            }
        }
    }

    #[test]
    fn two_frames_separated_by_exactly_t35_are_both_delivered() {
        for baud in [9600, 115_200] {
            let timing = LineConfig::new(baud, CharFormat::N1).timing();
            let mut a = FrameAssembler::new(timing);
            let (first, last) = feed(&mut a, &REQ, 0, timing.tc_us());
            assert!(first.is_empty());
            // no poll in between: the first byte of frame 2 closes frame 1
            let start = last + timing.t35_us() + timing.tc_us();
            let (closed, last2) = feed(&mut a, &REQ, start, timing.tc_us());
            assert_eq!(closed, vec![REQ.to_vec()], "baud {baud}");
            assert!(
                matches!(a.poll(last2 + timing.t35_us()), Some(RxEvent::Frame { bytes, .. }) if bytes == REQ)
            );
        }
    }

    #[test]
    fn short_long_and_flagged_frames() {
        let timing = LineConfig::DEFAULT.timing();
        let mut a = FrameAssembler::new(timing);
        let (_, last) = feed(&mut a, &REQ[..3], 0, timing.tc_us());
        assert_eq!(a.poll(last + timing.t35_us()), Some(RxEvent::TooShort));

        let long = [0x55u8; MAX_FRAME + 1];
        let (_, last) = feed(&mut a, &long, 100_000, timing.tc_us());
        assert_eq!(a.poll(last + timing.t35_us()), Some(RxEvent::Overrun));

        let (_, last) = feed(&mut a, &long[..MAX_FRAME], 200_000, timing.tc_us());
        assert!(
            matches!(a.poll(last + timing.t35_us()), Some(RxEvent::Frame { bytes, .. }) if bytes.len() == MAX_FRAME)
        );

        let t = 300_000;
        a.push(1, t, RxFlags::NONE);
        a.push(
            3,
            t + 87,
            RxFlags {
                parity: true,
                ..RxFlags::NONE
            },
        );
        a.push(0, t + 174, RxFlags::NONE);
        a.push(0, t + 261, RxFlags::NONE);
        assert!(matches!(
            a.poll(t + 261 + 1750),
            Some(RxEvent::Frame {
                parity_error: true,
                ..
            })
        ));

        a.push(
            1,
            t + 10_000,
            RxFlags {
                framing: true,
                ..RxFlags::NONE
            },
        );
        for i in 1..4 {
            a.push(0, t + 10_000 + 87 * i, RxFlags::NONE);
        }
        assert_eq!(a.end_of_frame(), Some(RxEvent::Broken));
    }

    #[test]
    fn timestamps_may_wrap() {
        let timing = LineConfig::DEFAULT.timing();
        let mut a = FrameAssembler::new(timing);
        let (_, last) = feed(&mut a, &REQ, u32::MAX - 200, timing.tc_us());
        assert!(last < 1000);
        assert!(matches!(
            a.poll(last.wrapping_add(timing.t35_us())),
            Some(RxEvent::Frame { .. })
        ));
    }
}
