//! How deep the firmware's stack has ever gone: the stack region is
//! painted at power-on and read back for `--stats`.
//!
//! Both images link with flip-link, which puts the stack at the bottom of
//! SRAM, below the statics: it grows down from the initial stack pointer
//! (the vector table's first word) towards the SRAM's start, where an
//! overflow faults instead of overwriting the statics. A power-on's SRAM
//! content is undefined on the chips (RM0440, RM0008); the model fills
//! the stack region with [`PAINT`] and leaves the rest zero, so the bytes
//! at the region's start still holding it are those no push, frame or
//! exception entry has reached since.

use crate::cpu::Uc;

/// The byte the stack region holds at power-on.
pub const PAINT: u8 = 0xA5;

/// The stack region: the SRAM's start up to the initial stack pointer.
fn region(uc: &Uc) -> Result<(u32, u32), String> {
    let chip = &uc.get_data().chip;
    let (base, flash) = (chip.sram_base, chip.flash_base);
    let mut sp = [0u8; 4];
    uc.mem_read(u64::from(flash), &mut sp)
        .map_err(|e| format!("vector table: {e:?}"))?;
    let sp = u32::from_le_bytes(sp);
    if sp < base || sp > base + chip.sram_len {
        return Err(format!("initial stack pointer {sp:#010x} outside SRAM"));
    }
    Ok((base, sp))
}

/// Fills the stack region with [`PAINT`] (power-on).
pub fn paint(uc: &mut Uc) -> Result<(), String> {
    let (base, sp) = region(uc)?;
    uc.mem_write(u64::from(base), &vec![PAINT; (sp - base) as usize])
        .map_err(|e| format!("stack paint: {e:?}"))
}

/// Bytes at the stack region's start never written since the paint
/// (whole words: a push writes words).
pub fn untouched(uc: &Uc) -> Result<u32, String> {
    let (base, sp) = region(uc)?;
    let bytes = uc
        .mem_read_as_vec(u64::from(base), (sp - base) as usize)
        .map_err(|e| format!("stack read: {e:?}"))?;
    Ok(leading_paint(&bytes))
}

/// The length of `bytes`' leading whole words that hold [`PAINT`] only.
fn leading_paint(bytes: &[u8]) -> u32 {
    let words = bytes
        .chunks_exact(4)
        .take_while(|w| w.iter().all(|&b| b == PAINT));
    4 * words.count() as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_untouched_part_ends_at_the_first_word_written() {
        let mut stack = vec![PAINT; 64];
        assert_eq!(leading_paint(&stack), 64);
        stack[41] = 0; // a byte of the word at 40
        assert_eq!(leading_paint(&stack), 40);
        stack[3] = PAINT ^ 1;
        assert_eq!(leading_paint(&stack), 0);
    }
}
