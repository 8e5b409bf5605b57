//! A limit's brake from the step the timer is at: the runs written ahead
//! of the timer (entries of several alike periods, `motion::burst`) are
//! cut to one period each, so the brake, which the next refill starts,
//! waits for a step per entry, not for a run per entry. All but the
//! newest: the refill that starts the brake writes its half while the DMA
//! plays the other, and that refill (the brake's first steps) takes
//! longer than a step per entry at the top rates; the newest entry's run,
//! the other half's last, gives it that time. HAL-free, so
//! `tests/firmware_calc.rs` includes it by path and runs it on the host.
//!
//! The DMA reads the buffer while this writes it. An entry is written only
//! while the DMA is at least two entries before it: the entry after the
//! one it is loading is read at the next update event at the earliest, and
//! the one after that a whole entry later (at least `MIN_ENTRY_TICKS`,
//! more than a check and a store take). The DMA's place is read again
//! before each store.

use modbus_drive::motion::burst::Burst;

/// Cuts the runs among the entries the DMA has not reached, in DIR level
/// `level` back from `newest` (the last entry written, which keeps its
/// run), to their first period. `unread()` is the index of the first
/// entry the DMA has not started. Returns the steps cut (all in the
/// direction of `level`).
pub fn cut_runs<const LEN: usize>(
    buffer: &mut [Burst; LEN],
    newest: usize,
    level: bool,
    mut unread: impl FnMut() -> usize,
) -> u32 {
    let len = LEN;
    let ahead = |from: usize, to: usize| (to + len - from) % len;
    let first = unread();
    let span = ahead(first, newest);
    // back from the newest while the level holds (a reversal in between
    // belongs to an older direction run)
    let mut lo = span + 1;
    while lo > 2 && buffer[(first + lo - 1) % len].dir_high() == level {
        lo -= 1;
    }
    let mut cut = 0;
    for i in lo..span {
        let k = (first + i) % len;
        let b = buffer[k];
        if b.periods() == 1 || b.pulse_ticks() == 0 {
            continue;
        }
        // the DMA only moves on (and never a buffer round while this runs)
        if i < ahead(first, unread()) + 2 {
            continue;
        }
        // SAFETY: `k` is inside `buffer`; a volatile store, so that it is
        // made after the check above and not merged or moved.
        unsafe { core::ptr::write_volatile(&mut buffer[k], b.first_period()) };
        cut += b.periods() - 1;
    }
    cut
}
