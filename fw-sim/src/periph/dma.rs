//! DMA controllers: RM0008 §13 (F1 DMA1, 7 channels) and RM0440 §12 (G4
//! DMA1 / DMA2, 6 channels each on the G431). The registers are the same on
//! both: ISR, IFCR, and per channel CCR, CNDTR, CPAR, CMAR.
//!
//! A channel transfers one data item per request of its peripheral (the
//! machine routes the requests: F1 fixed per channel, G4 through DMAMUX)
//! or, with MEM2MEM, all its items as soon as it is enabled. Each transfer
//! reads MSIZE / PSIZE at the source and writes the destination's size,
//! truncating or zero-extending (RM0008 table 79 "Programmable data width
//! and endian behavior", RM0440 table 84); PINC / MINC step the addresses;
//! CNDTR counts down; HTIF at half, TCIF at the end, GIF with either; in
//! circular mode CNDTR and the addresses reload at the end, else the
//! channel stays enabled with nothing left to do. A bus error (an address
//! in no memory or peripheral) sets TEIF and disables the channel. Several
//! requests at one instant are served by priority PL, then by channel
//! number (§13.3.2 / §12.4.2, the arbiter). A transfer takes no emulated
//! time (on the chip a few AHB cycles).
//!
//! The machine does the bus accesses (it owns the memories and the other
//! peripherals); this file keeps the registers and the channel state.

use super::Access;

const EN: u32 = 1;
const TCIE: u32 = 1 << 1;
const HTIE: u32 = 1 << 2;
const TEIE: u32 = 1 << 3;
const DIR: u32 = 1 << 4;
const CIRC: u32 = 1 << 5;
const PINC: u32 = 1 << 6;
const MINC: u32 = 1 << 7;
const MEM2MEM: u32 = 1 << 14;

const GIF: u32 = 1;
const TCIF: u32 = 2;
const HTIF: u32 = 4;
const TEIF: u32 = 8;

#[derive(Clone, Debug, Default)]
struct Channel {
    ccr: u32,
    cndtr: u32,
    cpar: u32,
    cmar: u32,
    /// The count and the addresses as the channel was enabled (the
    /// circular reload) and the addresses of the next transfer.
    n_start: u32,
    pa: u32,
    ma: u32,
}

/// One data item to move: read `src_size` bytes at `src`, write
/// `dst_size` bytes at `dst`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Transfer {
    pub src: u32,
    pub src_size: usize,
    pub dst: u32,
    pub dst_size: usize,
}

#[derive(Debug)]
pub struct Dma {
    g4: bool,
    ch: Vec<Channel>,
    isr: u32,
    irqs: Vec<usize>,
}

fn size(bits: u32) -> usize {
    match bits & 3 {
        0 => 1,
        1 => 2,
        _ => 4,
    }
}

impl Dma {
    /// `irqs`: the interrupt number of each channel.
    pub fn new(g4: bool, irqs: Vec<usize>) -> Self {
        Self {
            g4,
            ch: vec![Channel::default(); irqs.len()],
            isr: 0,
            irqs,
        }
    }

    /// No flag is set: every channel's interrupt line is low.
    pub fn quiet(&self) -> bool {
        self.isr == 0
    }

    /// Channel `c`'s interrupt line and its level.
    pub fn irq_level(&self, c: usize) -> (usize, bool) {
        let f = (self.isr >> (4 * c)) & 0xF;
        let ccr = self.ch[c].ccr;
        let on = (f & TCIF != 0 && ccr & TCIE != 0)
            || (f & HTIF != 0 && ccr & HTIE != 0)
            || (f & TEIF != 0 && ccr & TEIE != 0);
        (self.irqs[c], on)
    }
    pub fn channels(&self) -> usize {
        self.ch.len()
    }

    /// The channel's priority level PL (0 low .. 3 very high).
    pub fn priority(&self, c: usize) -> u32 {
        (self.ch[c].ccr >> 12) & 3
    }

    /// The next item channel `c` moves on a request, if it is enabled and
    /// has items left.
    pub fn next_transfer(&self, c: usize) -> Option<Transfer> {
        let ch = &self.ch[c];
        if ch.ccr & EN == 0 || ch.cndtr == 0 {
            return None;
        }
        let (psize, msize) = (size(ch.ccr >> 8), size(ch.ccr >> 10));
        Some(if ch.ccr & DIR != 0 {
            Transfer {
                src: ch.ma,
                src_size: msize,
                dst: ch.pa,
                dst_size: psize,
            }
        } else {
            Transfer {
                src: ch.pa,
                src_size: psize,
                dst: ch.ma,
                dst_size: msize,
            }
        })
    }

    /// Channel `c`'s item is done (`ok`) or hit a bus error.
    pub fn done(&mut self, c: usize, ok: bool) {
        let shift = 4 * c;
        let ch = &mut self.ch[c];
        if !ok {
            ch.ccr &= !EN;
            self.isr |= (TEIF | GIF) << shift;
            return;
        }
        if ch.ccr & PINC != 0 {
            ch.pa = ch.pa.wrapping_add(size(ch.ccr >> 8) as u32);
        }
        if ch.ccr & MINC != 0 {
            ch.ma = ch.ma.wrapping_add(size(ch.ccr >> 10) as u32);
        }
        ch.cndtr -= 1;
        if ch.cndtr == ch.n_start / 2 && ch.n_start > 1 {
            self.isr |= (HTIF | GIF) << shift;
        }
        if ch.cndtr == 0 {
            self.isr |= (TCIF | GIF) << shift;
            if ch.ccr & CIRC != 0 {
                ch.cndtr = ch.n_start;
                ch.pa = ch.cpar;
                ch.ma = ch.cmar;
            }
        }
    }

    /// A memory-to-memory channel that was just enabled: the machine moves
    /// all its items at once.
    pub fn mem2mem_ready(&self, c: usize) -> bool {
        let ch = &self.ch[c];
        ch.ccr & (EN | MEM2MEM) == (EN | MEM2MEM) && ch.cndtr > 0
    }

    /// Which channel a register offset belongs to, and the register.
    fn decode(&self, off: u32) -> Option<(usize, u32)> {
        if off < 0x08 {
            return None;
        }
        let c = ((off - 0x08) / 0x14) as usize;
        (c < self.ch.len()).then_some((c, (off - 0x08) % 0x14))
    }

    pub fn read(&self, off: u32) -> Access {
        match off {
            0x00 => return Access::Ok(self.isr),
            0x04 => return Access::Ok(0),
            _ => {}
        }
        let Some((c, r)) = self.decode(off) else {
            return Access::Unmodelled;
        };
        let ch = &self.ch[c];
        Access::Ok(match r {
            0x00 => ch.ccr,
            0x04 => ch.cndtr,
            0x08 => ch.cpar,
            _ => ch.cmar,
        })
    }

    /// A register write; returns the channel that was just enabled, if any.
    pub fn write(&mut self, off: u32, v: u32) -> (Access, Option<usize>) {
        match off {
            // ISR is read-only
            0x00 => return (Access::Ok(0), None),
            0x04 => {
                for c in 0..self.ch.len() {
                    let m = (v >> (4 * c)) & 0xF;
                    // CGIF clears all four flags of the channel
                    let clear = if m & GIF != 0 { 0xF } else { m };
                    self.isr &= !(clear << (4 * c));
                }
                return (Access::Ok(0), None);
            }
            _ => {}
        }
        let Some((c, r)) = self.decode(off) else {
            return (Access::Unmodelled, None);
        };
        let g4 = self.g4;
        let ch = &mut self.ch[c];
        let enabled = ch.ccr & EN != 0;
        let mut started = None;
        match r {
            0x00 => {
                // G4: every bit but EN is read-only while EN is set;
                // F1: the manual forbids changing them then, kept here
                let v = if g4 && enabled {
                    (ch.ccr & !EN) | (v & EN)
                } else {
                    v & 0x7FFF
                };
                if v & EN != 0 && !enabled {
                    ch.n_start = ch.cndtr;
                    ch.pa = ch.cpar;
                    ch.ma = ch.cmar;
                    started = Some(c);
                }
                ch.ccr = v;
            }
            0x04 if !enabled => ch.cndtr = v & 0xFFFF,
            0x08 if !enabled => ch.cpar = v,
            0x0C if !enabled => ch.cmar = v,
            // written while enabled: no effect (G4 read-only, F1 "must not")
            _ => {}
        }
        (Access::Ok(0), started)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Channel 3 (index 2) memory → peripheral, 16-bit both, MINC, `n`
    /// items, circular or not.
    fn channel(n: u32, circ: bool) -> Dma {
        let mut d = Dma::new(false, (11..18).collect());
        let c = 0x08 + 0x14 * 2;
        d.write(c + 0x04, n);
        d.write(c + 0x08, 0x4000_042C);
        d.write(c + 0x0C, 0x2000_0100);
        let circ = if circ { CIRC } else { 0 };
        d.write(
            c,
            EN | DIR | MINC | circ | (1 << 8) | (1 << 10) | HTIE | TCIE,
        );
        d
    }

    #[test]
    fn a_channel_moves_its_count_then_stops_with_ht_and_tc() {
        let mut d = channel(4, false);
        let mut seen = Vec::new();
        while let Some(t) = d.next_transfer(2) {
            seen.push(t);
            d.done(2, true);
            if seen.len() == 2 {
                assert_eq!(d.isr >> 8, HTIF | GIF, "half of 4 done");
                assert_eq!(d.irq_level(2), (13, true));
            }
        }
        assert_eq!(seen.len(), 4, "CNDTR items, no more");
        assert_eq!(seen[3].src, 0x2000_0106);
        assert!(seen.iter().all(|t| t.dst == 0x4000_042C && t.dst_size == 2));
        assert_eq!(d.isr >> 8, HTIF | TCIF | GIF);
        assert!(matches!(d.read(0x08 + 0x14 * 2 + 4), Access::Ok(0)));
        // CGIF3 clears the channel's flags, its interrupt falls
        d.write(0x04, GIF << 8);
        assert_eq!(d.isr, 0);
        assert_eq!(d.irq_level(2), (13, false));
    }

    #[test]
    fn circular_mode_reloads_the_count_and_the_address() {
        let mut d = channel(3, true);
        let srcs: Vec<u32> = (0..7)
            .map(|_| {
                let t = d.next_transfer(2).unwrap();
                d.done(2, true);
                t.src
            })
            .collect();
        let base = 0x2000_0100;
        assert_eq!(
            srcs,
            [base, base + 2, base + 4, base, base + 2, base + 4, base]
        );
        assert!(matches!(d.read(0x08 + 0x14 * 2 + 4), Access::Ok(2)));
    }

    #[test]
    fn a_bus_error_sets_te_and_disables_the_channel() {
        let mut d = channel(3, false);
        d.write(0x08 + 0x14 * 2, EN | DIR | TEIE);
        d.done(2, false);
        assert_eq!(d.isr >> 8, TEIF | GIF);
        assert_eq!(d.next_transfer(2), None);
        assert_eq!(d.irq_level(2), (13, true));
    }

    #[test]
    fn registers_are_locked_while_enabled_on_the_g4() {
        let mut d = Dma::new(true, (11..17).collect());
        d.write(0x0C, 5);
        d.write(0x08, EN | DIR);
        d.write(0x0C, 9); // CNDTR while enabled: ignored
        d.write(0x08, EN | CIRC); // only EN may change
        assert!(matches!(d.read(0x0C), Access::Ok(5)));
        assert!(matches!(d.read(0x08), Access::Ok(v) if v == EN | DIR));
        assert!(matches!(d.read(0x08 + 0x14 * 6), Access::Unmodelled));
    }
}
