//! Reads the parameter region as the firmware before the journal left it:
//! a `sequential-storage` 8 map with key 0 = saved set and 1 = backup set,
//! each value one record (`record.rs`). The journal (`storage.rs`) finds no
//! page of its own on such a region, takes the two sets over from here once
//! and never looks at this layout again. Only reading is needed, so the
//! crate itself is not linked.
//!
//! The layout, as sequential-storage 8.0 writes it (its crate root and its
//! `item` and `map` modules), with `word` = the larger of the flash's read and write sizes:
//!
//! * page state: the first and the last `READ_SIZE` bytes of a page are
//!   markers, "marked" when at least four of their bits are 0. Neither
//!   marked = open (erased), first only = partial open (being filled), both
//!   = closed (full); the last only is an erase a cut left unfinished, which
//!   the crate's repair finishes (its items were moved before): open;
//! * items from `page + word` to `page end − word`: an 8-byte header
//!   (CRC-32 of the data, data length u16, CRC-16 of the length), the data
//!   at `header + 8` rounded up to a word, the next header after the data
//!   rounded up to a word. A header that reads erased ends the page; one
//!   whose length CRC fails is skipped a word at a time; a data CRC of 0
//!   means a removed item;
//! * the map keeps the page after the partial-open one open; a store that
//!   fills its page closes it, partially closes the next and moves the live
//!   items of the page after that (the oldest) into it before erasing it.
//!   A fetch looks in the partial-open page, then in the closed pages
//!   before it, and takes the last item of the key.
//!
//! A power cut inside that move leaves a partial-open page whose next page
//! is not open: the move is then incomplete, everything it copied is still
//! in the page being emptied, so this reader ignores the partial page and
//! reads the closed pages, as the crate's own repair would.

use core::ops::Range;

use embedded_storage::nor_flash::NorFlash;

/// Where the sets of an old region are, and which page the journal may
/// take first without losing any of them.
pub(super) struct OldSets {
    /// Per slot (0 saved, 1 backup): flash offset and length of the record.
    sets: [Option<(u32, usize)>; 2],
    /// Page index (in the region) that holds nothing the sets need.
    free_page: u32,
}

impl OldSets {
    /// Per slot (0 saved, 1 backup): flash offset and length of the record.
    #[inline]
    pub const fn sets(&self) -> [Option<(u32, usize)>; 2] {
        self.sets
    }

    /// Page index (in the region) that holds nothing the sets need.
    #[inline]
    pub const fn free_page(&self) -> u32 {
        self.free_page
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum State {
    Open,
    Partial,
    Closed,
}

/// Reads the old map on `range` of `flash` (the journal's region). An item
/// is read into `scratch`: one longer than it (key and record) is not a set.
pub(super) fn read_old<F: NorFlash>(
    flash: &mut F,
    range: &Range<u32>,
    scratch: &mut [u8],
) -> Result<OldSets, F::Error> {
    let page = F::ERASE_SIZE as u32;
    let pages = (range.end - range.start) / page;
    let mut states = [State::Open; MAX_PAGES];
    for p in 0..pages.min(MAX_PAGES as u32) {
        let at = range.start + p * page;
        let first = marked(flash, at)?;
        let last = marked(flash, at + page - 1)?;
        // The last marker without the first is an erase the power cut
        // short; the crate finishes it, its items having been moved.
        states[p as usize] = match (first, last) {
            (false, _) => State::Open,
            (true, false) => State::Partial,
            (true, true) => State::Closed,
        };
    }
    let next = |p: u32| (p + 1) % pages;
    let prev = |p: u32| (p + pages - 1) % pages;
    let state = |p: u32| states[p as usize];
    // The newest page the map would read.
    let partial = (0..pages).find(|&p| state(p) == State::Partial);
    let newest = match partial {
        Some(p) if state(next(p)) == State::Open => Some(p),
        Some(p) => Some(prev(p)).filter(|&q| state(q) == State::Closed),
        None => (0..pages)
            .find(|&p| state(p) == State::Open)
            .map(prev)
            .filter(|&q| state(q) == State::Closed),
    };
    let mut out = OldSets {
        sets: [None, None],
        free_page: 0,
    };
    let Some(newest) = newest else {
        return Ok(out);
    };
    out.free_page = next(newest);
    // the closed pages before it, oldest first
    let mut oldest = newest;
    for _ in 2..pages {
        if state(prev(oldest)) != State::Closed {
            break;
        }
        oldest = prev(oldest);
    }
    let mut p = oldest;
    loop {
        read_page(flash, range.start + p * page, page, scratch, &mut out.sets)?;
        if p == newest {
            return Ok(out);
        }
        p = next(p);
    }
}

/// Regions up to this many pages are read (the boards have 2 and 4).
const MAX_PAGES: usize = 8;

/// The store works with a `READ_SIZE` of 1 only, so a marker is one byte.
fn marked<F: NorFlash>(flash: &mut F, at: u32) -> Result<bool, F::Error> {
    let mut b = [0u8];
    flash.read(at, &mut b)?;
    Ok(b[0].count_zeros() >= 4)
}

/// Every item of one page, in order; a later one of a key replaces the
/// earlier.
fn read_page<F: NorFlash>(
    flash: &mut F,
    start: u32,
    page: u32,
    buf: &mut [u8],
    sets: &mut [Option<(u32, usize)>; 2],
) -> Result<(), F::Error> {
    let word = F::READ_SIZE.max(F::WRITE_SIZE) as u32;
    let up = |n: u32| n.next_multiple_of(word);
    let end = start + page - word;
    let mut at = start + word;
    while at + up(8) <= end {
        let mut h = [0u8; 8];
        flash.read(at, &mut h)?;
        if h == [0xFF; 8] {
            break;
        }
        let len = u16::from_le_bytes([h[4], h[5]]);
        let data = at + up(8);
        let next = data + up(u32::from(len));
        if crc16(&h[4..6]) != u16::from_le_bytes([h[6], h[7]]) || next > end {
            at += word;
            continue;
        }
        let crc = u32::from_le_bytes([h[0], h[1], h[2], h[3]]);
        let len = usize::from(len);
        if crc != 0 && (2..=buf.len()).contains(&len) {
            flash.read(data, &mut buf[..len])?;
            let key = usize::from(buf[0]);
            if key < 2 && crc32(&buf[..len]) == crc {
                sets[key] = Some((data + 1, len - 1));
            }
        }
        at = next;
    }
    Ok(())
}

/// The crate's length check: CRC-16F/4.2 (Koopman 0x1a2e, reflected),
/// never 0xFFFF.
fn crc16(data: &[u8]) -> u16 {
    let mut crc = 0xFFFFu16;
    for &b in data {
        crc ^= u16::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0x1A2E
            } else {
                crc >> 1
            };
        }
    }
    match !crc {
        0xFFFF => 0xFFFE,
        c => c,
    }
}

/// The crate's data check: CRC-32C from 0xEEEE_EEEE, then never 0 and
/// never a first byte of 0x00 or 0xFF.
fn crc32(data: &[u8]) -> u32 {
    let mut crc = 0xEEEE_EEEEu32;
    for &b in data {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0x82F6_3B78
            } else {
                crc >> 1
            };
        }
    }
    match !crc {
        0 => 1,
        c if c as u8 == 0 || c as u8 == 0xFF => c ^ 1,
        c => c,
    }
}
