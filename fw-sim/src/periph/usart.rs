//! USART1 in asynchronous mode: RM0440 §37 (G4: ISR/ICR/RDR/TDR, receiver
//! timeout RTOR/RTOF, TEACK/REACK, hardware driver enable CR3.DEM with
//! DEAT/DEDT) and RM0008 §27 (F1: SR/DR, flags cleared by an SR read then a
//! DR access). Characters take their bit times from BRR, PRESC, M, PCE and
//! STOP at the USART's kernel clock. Synchronous, LIN,
//! smartcard, IrDA and half-duplex are not modelled (`Unsupported`).
//! FIFO mode (G4 FIFOEN, RM0440 §37.5.3): eight characters each way, RXFNE
//! / TXFNF in the RXNE / TXE places, TXFE and RXFF; the FIFO threshold
//! interrupts are not modelled.

use std::collections::VecDeque;

use super::Access;
use crate::clock::PS_PER_S;

/// A character on the RX wire, with what the line did to it.
#[derive(Clone, Copy, Debug, Default)]
pub struct RxChar {
    pub byte: u8,
    pub parity_error: bool,
    pub framing_error: bool,
    pub noise: bool,
    pub brk: bool,
}

#[derive(Debug)]
pub struct Usart {
    g4: bool,
    pub fck: u64,
    cr1: u32,
    cr2: u32,
    cr3: u32,
    brr: u32,
    gtpr: u32,
    rtor: u32,
    presc: u32,
    /// ISR (G4) / SR (F1) flags, G4 bit positions for both (F1's are the same
    /// for bits 0..9).
    isr: u32,
    /// Received characters not yet read (one, or up to eight in FIFO mode).
    rx_fifo: VecDeque<u16>,
    /// F1: flags seen by the last SR read (cleared by the next DR read).
    f1_sr_seen: u32,
    /// Characters arriving: (time the stop bit ends, character).
    pub rx: VecDeque<(u64, RxChar)>,
    last_rx_end: Option<u64>,
    rto_armed: bool,
    idle_armed: bool,
    /// Characters written and not yet in the shift register.
    tx_fifo: VecDeque<u8>,
    /// The character in the shift register: (start bit time, end of stop
    /// bit, byte, the driver was on at its start bit).
    shift: Option<(u64, u64, u8, bool)>,
    /// Driver enable (G4 hardware DE): on since, off at.
    de_on: bool,
    de_off_at: Option<u64>,
    /// Transmitted characters: (start, end, byte, the driver was on for
    /// the whole character), for the line.
    pub tx_out: Vec<(u64, u64, u8, bool)>,
    /// The DE pin is a GPIO at this level (F1, or G4 with the pin not in
    /// its USART alternate function); None: the USART's own DE output.
    pub gpio_de: Option<bool>,
    /// Changes of the transceiver's driver enable (either the USART's own
    /// DE output or the board's GPIO), for the line trace.
    pub de_edges: Vec<(u64, bool)>,
    /// Print every character and timeout (FW_SIM_DEBUG_UART).
    pub debug: bool,
}

// ISR bits (G4 numbering; F1 SR uses the same for PE..CTS)
const PE: u32 = 1;
const FE: u32 = 1 << 1;
const NE: u32 = 1 << 2;
const ORE: u32 = 1 << 3;
const IDLE: u32 = 1 << 4;
const RXNE: u32 = 1 << 5;
const TC: u32 = 1 << 6;
const TXE: u32 = 1 << 7;
const RTOF: u32 = 1 << 11;
const BUSY: u32 = 1 << 16;
const TXFE: u32 = 1 << 23;
const RXFF: u32 = 1 << 24;
const TEACK: u32 = 1 << 21;
const REACK: u32 = 1 << 22;

impl Usart {
    pub fn new(g4: bool) -> Self {
        Self {
            g4,
            fck: 8_000_000,
            cr1: 0,
            cr2: 0,
            cr3: 0,
            brr: 0,
            gtpr: 0,
            rtor: 0,
            presc: 0,
            isr: TC | TXE,
            rx_fifo: VecDeque::new(),
            f1_sr_seen: 0,
            rx: VecDeque::new(),
            last_rx_end: None,
            rto_armed: false,
            idle_armed: false,
            tx_fifo: VecDeque::new(),
            shift: None,
            de_on: false,
            de_off_at: None,
            tx_out: Vec::new(),
            gpio_de: None,
            de_edges: Vec::new(),
            debug: std::env::var_os("FW_SIM_DEBUG_UART").is_some(),
        }
    }

    fn ue(&self) -> bool {
        let bit = if self.g4 { 1 } else { 1 << 13 };
        self.cr1 & bit != 0
    }
    fn te(&self) -> bool {
        self.ue() && self.cr1 & (1 << 3) != 0
    }
    fn re(&self) -> bool {
        self.ue() && self.cr1 & (1 << 2) != 0
    }
    fn pce(&self) -> bool {
        self.cr1 & (1 << 10) != 0
    }
    /// Bits per character: start + data (incl. parity) + stop.
    pub fn char_bits(&self) -> u32 {
        let data = if self.g4 {
            match (self.cr1 >> 28 & 1, self.cr1 >> 12 & 1) {
                (0, 0) => 8,
                (0, 1) => 9,
                _ => 7,
            }
        } else if self.cr1 & (1 << 12) != 0 {
            9
        } else {
            8
        };
        let stop = if (self.cr2 >> 12) & 3 == 2 { 2 } else { 1 };
        1 + data + stop
    }
    /// One bit time in ps (0 if the baud rate is not set).
    pub fn bit_ps(&self) -> u64 {
        let presc = [1, 2, 4, 6, 8, 10, 12, 16, 32, 64, 128, 256][(self.presc as usize).min(11)];
        let over8 = self.cr1 & (1 << 15) != 0;
        let div = if over8 {
            ((self.brr & 0xFFF0) | ((self.brr & 7) << 1)) as u128 / 2
        } else {
            self.brr as u128
        };
        if div == 0 {
            return 0;
        }
        (div * presc as u128 * PS_PER_S / self.fck as u128) as u64
    }
    pub fn char_ps(&self) -> u64 {
        self.bit_ps() * self.char_bits() as u64
    }
    /// The line's t3.5 at the current baud (Modbus over Serial Line
    /// §2.5.1.1: 3.5 character times, fixed at 1750 µs above 19200 baud).
    pub fn t35_ps(&self) -> u64 {
        const FIXED: u64 = 1_750_000_000;
        let bit = self.bit_ps();
        if bit == 0 || bit < PS_PER_S as u64 / 19_200 {
            FIXED
        } else {
            self.char_ps() * 7 / 2
        }
    }
    /// Receiver on with its interrupt enabled: the firmware listens.
    pub fn rx_armed(&self) -> bool {
        self.re() && self.cr1 & (1 << 5) != 0
    }
    /// Receiver timeout in ps (G4, RTOEN set), else None.
    fn rto_ps(&self) -> Option<u64> {
        (self.g4 && self.cr2 & (1 << 23) != 0)
            .then(|| (self.rtor & 0xFF_FFFF) as u64 * self.bit_ps())
    }
    fn dem(&self) -> bool {
        self.g4 && self.cr3 & (1 << 14) != 0
    }
    /// The level of the G4 DE output (after DEP), if DEM is on.
    pub fn de_output(&self) -> Option<bool> {
        self.dem()
            .then_some(self.de_on ^ (self.cr3 & (1 << 15) != 0))
    }
    pub fn transmitting(&self) -> bool {
        self.shift.is_some() || !self.tx_fifo.is_empty()
    }

    pub fn irq_level(&self) -> bool {
        let i = self.isr;
        let c = self.cr1;
        (c & (1 << 5) != 0 && i & (RXNE | ORE) != 0)
            || (c & (1 << 6) != 0 && i & TC != 0)
            || (c & (1 << 7) != 0 && i & TXE != 0)
            || (self.g4 && c & (1 << 30) != 0 && i & TXFE != 0)
            || (self.g4 && c & (1 << 31) != 0 && i & RXFF != 0)
            || (c & (1 << 4) != 0 && i & IDLE != 0)
            || (c & (1 << 8) != 0 && i & PE != 0)
            || (self.g4 && c & (1 << 26) != 0 && i & RTOF != 0)
            || (self.cr3 & 1 != 0 && i & (FE | NE | ORE) != 0)
    }

    /// The transceiver drives the bus (DE high): its receiver is off then
    /// (/RE tied to DE on the board).
    pub fn driving(&self) -> bool {
        self.gpio_de
            .unwrap_or_else(|| self.de_output().unwrap_or(false))
    }

    pub fn sync(&mut self, t: u64) {
        loop {
            let mut next: Option<(u64, u8)> = None;
            let mut consider = |at: Option<u64>, what: u8| {
                if let Some(at) = at {
                    if at <= t && next.is_none_or(|(n, _)| at < n) {
                        next = Some((at, what));
                    }
                }
            };
            consider(self.rx.front().map(|r| r.0), 0);
            consider(self.shift.map(|s| s.1), 1);
            let rto = match (self.rto_armed, self.last_rx_end, self.rto_ps()) {
                (true, Some(l), Some(p)) if p > 0 => Some(l + p),
                _ => None,
            };
            consider(rto, 2);
            let idle = match (self.idle_armed, self.last_rx_end) {
                (true, Some(l)) => Some(l + self.char_ps()),
                _ => None,
            };
            consider(idle, 3);
            consider(self.de_off_at, 4);
            let Some((at, what)) = next else { return };
            match what {
                0 => {
                    let (end, c) = self.rx.pop_front().unwrap();
                    if self.debug {
                        eprintln!(
                            "usart: rx {:#04x} at {} ns (re {}, driving {}, isr {:#x})",
                            c.byte,
                            end / 1000,
                            self.re(),
                            self.driving(),
                            self.isr
                        );
                    }
                    // the receiver is blind while our own driver is on
                    let _ = end;
                    if self.re() && !self.driving() {
                        self.receive(c);
                        self.last_rx_end = Some(end);
                        self.rto_armed = true;
                        self.idle_armed = true;
                    }
                }
                1 => {
                    let (s, e, b, on) = self.shift.take().unwrap();
                    if self.debug {
                        eprintln!(
                            "usart: tx {b:#04x} {} ns .. {} ns, driver on {}",
                            s / 1000,
                            e / 1000,
                            on && self.driving()
                        );
                    }
                    self.tx_out.push((s, e, b, on && self.driving()));
                    if let Some(next) = self.tx_fifo.pop_front() {
                        self.shift = Some((at, at + self.char_ps(), next, self.driving()));
                        self.isr |= TXE;
                    } else {
                        self.isr |= TC;
                        if self.dem() {
                            let dedt = ((self.cr1 >> 16) & 0x1F) as u64 * self.bit_ps() / 16;
                            self.de_off_at = Some(at + dedt);
                        }
                    }
                }
                2 => {
                    if self.debug {
                        eprintln!("usart: receiver timeout at {} ns", at / 1000);
                    }
                    self.isr |= RTOF;
                    self.rto_armed = false;
                }
                3 => {
                    self.isr |= IDLE;
                    self.idle_armed = false;
                }
                _ => {
                    self.de_on = false;
                    self.de_off_at = None;
                    // on the pin only while it is in the USART's function
                    if self.gpio_de.is_none() {
                        self.de_edges.push((at, false));
                    }
                }
            }
        }
    }

    fn receive(&mut self, c: RxChar) {
        if self.rx_fifo.len() >= self.depth() {
            // the previous character was not read: overrun, this one is lost
            // (G4 unless OVRDIS)
            if !(self.g4 && self.cr3 & (1 << 12) != 0) {
                self.isr |= ORE;
            }
            return;
        }
        let stop = if (self.cr2 >> 12) & 3 == 2 { 2 } else { 1 };
        let data = self.char_bits() - 1 - stop;
        let mut b = if c.brk { 0 } else { c.byte as u16 };
        if self.pce() {
            // the parity bit is not part of the data
            b &= (1 << (data - 1)) - 1;
        }
        self.rx_fifo.push_back(b);
        self.isr |= RXNE;
        if c.parity_error && self.pce() {
            self.isr |= PE;
        }
        if c.framing_error || c.brk {
            self.isr |= FE;
        }
        if c.noise {
            self.isr |= NE;
        }
    }

    /// Time of the next line event (character in or out, timeouts, DE).
    pub fn next_event(&self) -> Option<u64> {
        let mut v: Vec<u64> = Vec::new();
        if let Some(r) = self.rx.front() {
            v.push(r.0);
        }
        if let Some(s) = self.shift {
            v.push(s.1);
        }
        if let (true, Some(l), Some(p)) = (self.rto_armed, self.last_rx_end, self.rto_ps()) {
            if p > 0 {
                v.push(l + p);
            }
        }
        if let (true, Some(l)) = (self.idle_armed, self.last_rx_end) {
            v.push(l + self.char_ps());
        }
        if let Some(d) = self.de_off_at {
            v.push(d);
        }
        v.into_iter().min()
    }

    fn start_tx(&mut self, b: u8, t: u64) {
        if !self.te() {
            return;
        }
        self.isr &= !TC;
        if self.shift.is_none() {
            let mut start = t;
            if self.dem() && !self.de_on {
                self.de_on = true;
                if self.gpio_de.is_none() {
                    self.de_edges.push((t, true));
                }
                start += ((self.cr1 >> 21) & 0x1F) as u64 * self.bit_ps() / 16;
            }
            self.de_off_at = None;
            self.shift = Some((start, start + self.char_ps(), b, self.driving()));
            self.isr |= TXE;
        } else if self.tx_fifo.len() < self.depth() {
            self.tx_fifo.push_back(b);
            if self.tx_fifo.len() >= self.depth() {
                self.isr &= !TXE;
            }
        }
    }

    fn status(&self) -> u32 {
        let mut i = self.isr;
        if self.g4 {
            if self.te() {
                i |= TEACK;
            }
            if self.re() {
                i |= REACK;
            }
            if self.transmitting() {
                i |= BUSY;
            }
            if self.fifo_mode() && self.tx_fifo.is_empty() {
                i |= TXFE;
            }
            if self.fifo_mode() && self.rx_fifo.len() >= 8 {
                i |= RXFF;
            }
        }
        i
    }

    fn disable(&mut self) {
        // UE = 0: current operations discarded, status flags at reset
        self.isr = TC | TXE;
        self.tx_fifo.clear();
        self.rx_fifo.clear();
        self.shift = None;
        self.de_on = false;
        self.de_off_at = None;
        self.rto_armed = false;
        self.idle_armed = false;
    }

    fn fifo_mode(&self) -> bool {
        self.g4 && self.cr1 & (1 << 29) != 0
    }
    fn depth(&self) -> usize {
        if self.fifo_mode() {
            8
        } else {
            1
        }
    }
    /// RDR read: the oldest character; RXNE (RXFNE) while any is left.
    fn pop_rx(&mut self) -> u16 {
        let b = self.rx_fifo.pop_front().unwrap_or(0);
        if self.rx_fifo.is_empty() {
            self.isr &= !RXNE;
        }
        b
    }

    pub fn read(&mut self, off: u32) -> Access {
        Access::Ok(if self.g4 {
            match off {
                0x00 => self.cr1,
                0x04 => self.cr2,
                0x08 => self.cr3,
                0x0C => self.brr,
                0x10 => self.gtpr,
                0x14 => self.rtor,
                0x18 => 0,
                0x1C => self.status(),
                0x20 => 0,
                0x24 => self.pop_rx() as u32,
                0x28 => 0,
                0x2C => self.presc,
                _ => return Access::Unmodelled,
            }
        } else {
            match off {
                0x00 => {
                    let s = self.status() & 0x3FF;
                    self.f1_sr_seen = s;
                    s
                }
                0x04 => {
                    self.isr &= !(self.f1_sr_seen & (PE | FE | NE | ORE | IDLE));
                    self.f1_sr_seen = 0;
                    self.pop_rx() as u32
                }
                0x08 => self.brr,
                0x0C => self.cr1,
                0x10 => self.cr2,
                0x14 => self.cr3,
                0x18 => self.gtpr,
                _ => return Access::Unmodelled,
            }
        })
    }

    pub fn write(&mut self, off: u32, v: u32, t: u64) -> Access {
        if self.g4 {
            let ue = self.ue();
            match off {
                0x00 => {
                    // M, OVER8, PCE, PS, WAKE, DEAT, DEDT, FIFOEN: only while UE = 0
                    const LOCKED: u32 = (1 << 28)
                        | (1 << 12)
                        | (1 << 15)
                        | (1 << 10)
                        | (1 << 9)
                        | (1 << 11)
                        | (0x3FF << 16)
                        | (1 << 29);
                    let v = if ue {
                        (v & !LOCKED) | (self.cr1 & LOCKED)
                    } else {
                        v
                    };
                    self.cr1 = v;
                    if ue && v & 1 == 0 {
                        self.disable();
                    }
                }
                0x04 => {
                    if v & (1 << 14) != 0 || v & (1 << 11) != 0 {
                        return Access::Unsupported("USART LIN / synchronous mode");
                    }
                    self.cr2 = if ue {
                        (v & (1 << 23)) | (self.cr2 & !(1 << 23))
                    } else {
                        v
                    };
                }
                0x08 => {
                    if v & ((1 << 3) | (1 << 5) | (1 << 1)) != 0 {
                        return Access::Unsupported("USART half-duplex / smartcard / IrDA");
                    }
                    const LOCKED: u32 = (1 << 14) | (1 << 15) | (1 << 12) | (1 << 11);
                    if v & ((1 << 28) | (1 << 23)) != 0 {
                        return Access::Unsupported(
                            "USART FIFO threshold interrupts (RXFTIE / TXFTIE)",
                        );
                    }
                    self.cr3 = if ue {
                        (v & !LOCKED) | (self.cr3 & LOCKED)
                    } else {
                        v
                    };
                }
                0x0C => {
                    if !ue {
                        self.brr = v & 0xFFFF
                    }
                }
                0x10 => self.gtpr = v,
                0x14 => self.rtor = v,
                0x18 => {
                    if v & (1 << 3) != 0 {
                        self.pop_rx();
                    }
                }
                0x20 => {
                    // ICR: PECF FECF NECF ORECF IDLECF .. TCCF .. RTOCF
                    let mut clr = v & (PE | FE | NE | ORE | IDLE | TC);
                    if v & (1 << 11) != 0 {
                        clr |= RTOF;
                    }
                    self.isr &= !clr;
                }
                0x24 => {}
                0x28 => self.start_tx(v as u8, t),
                0x2C => {
                    if !ue {
                        self.presc = v & 0xF
                    }
                }
                _ => return Access::Unmodelled,
            }
        } else {
            match off {
                // rc_w0 for RXNE and TC; the error flags are read-only
                0x00 => {
                    if v & RXNE == 0 {
                        self.rx_fifo.clear();
                    }
                    self.isr &= !((!v) & (RXNE | TC));
                }
                0x04 => {
                    if self.f1_sr_seen & TC != 0 {
                        self.isr &= !TC;
                    }
                    self.f1_sr_seen = 0;
                    self.start_tx(v as u8, t)
                }
                0x08 => self.brr = v & 0xFFFF,
                0x0C => {
                    let was = self.ue();
                    self.cr1 = v & 0x3FFF;
                    if was && !self.ue() {
                        self.disable();
                    }
                }
                0x10 => {
                    if v & (1 << 14) != 0 || v & (1 << 11) != 0 {
                        return Access::Unsupported("USART LIN / synchronous mode");
                    }
                    self.cr2 = v
                }
                0x14 => {
                    if v & ((1 << 3) | (1 << 5) | (1 << 1)) != 0 {
                        return Access::Unsupported("USART half-duplex / smartcard / IrDA");
                    }
                    self.cr3 = v
                }
                0x18 => self.gtpr = v,
                _ => return Access::Unmodelled,
            }
        }
        Access::Ok(0)
    }
}
