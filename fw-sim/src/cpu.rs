//! The CPU: unicorn's Cortex-M3 / Cortex-M4F core with exactly the chip's
//! memories mapped (flash below the parameter pages read-only, the parameter
//! pages through the flash model, SRAM read-write), the peripheral space and
//! the system control space routed to the model, and exception entry and
//! return done here (ARMv7-M ARM B1.5.6 / B1.5.8), since unicorn has no
//! NVIC: the core always runs in Thread mode as far as unicorn knows, and a
//! branch to an EXC_RETURN value is a fetch from 0xFFFF_FFxx, which stops
//! the slice and is unstacked here.
//!
//! Timing: one instruction = one cycle at SYSCLK (the CPI assumption; see
//! docs/fw-sim.md), counted per translated block; exception entry and
//! return cost 12 and 10 cycles (the Cortex-M3/M4 figures without wait
//! states).

use unicorn_engine::unicorn_const::{Arch, HookType, MemType, Mode, Prot};
use unicorn_engine::{ArmCpuModel, RegisterARM as R, Unicorn};

use crate::chip::Kind;
use crate::elf::Image;
use crate::machine::Machine;
use crate::mem::HostMem;

pub type Uc = Unicorn<'static, Machine>;

pub const ENTRY_CYCLES: u64 = 12;
pub const RETURN_CYCLES: u64 = 10;
/// Fetches at or above this address are EXC_RETURN values.
const EXC_RETURN_BASE: u64 = 0xFFFF_FF00;

/// Where the parameter pages start (the rest of flash is code).
pub fn param_base(m: &Machine) -> u32 {
    m.flash.region_base
}

pub fn create(image: &Image, machine: Machine) -> Result<Uc, String> {
    let chip = machine.chip;
    let mut uc = Unicorn::new_with_data(Arch::ARM, Mode::THUMB | Mode::MCLASS, machine)
        .map_err(|e| format!("unicorn: {e:?}"))?;
    let model = match chip.kind {
        Kind::G431 => ArmCpuModel::CORTEX_M4,
        Kind::F103 => ArmCpuModel::CORTEX_M3,
    };
    uc.ctl_set_cpu_model(model as i32)
        .map_err(|e| format!("cpu model: {e:?}"))?;
    let pb = param_base(uc.get_data()) as u64;
    let plen = uc.get_data().flash.data.len() as u64;
    let fb = chip.flash_base as u64;
    // code flash: what the CPU fetches and reads; a store is a fault. It
    // and SRAM are host buffers the machine holds too, for DMA (mem.rs)
    let code = HostMem::new(chip.flash_base, (pb - fb) as usize);
    // SAFETY: the buffer is leaked (lives as long as the process) and is
    // `pb - fb` bytes long
    unsafe { uc.mem_map_ptr(fb, pb - fb, Prot::READ | Prot::EXEC, code.ptr().cast()) }
        .map_err(|e| format!("map flash: {e:?}"))?;
    if pb + plen != chip.flash_end() as u64 {
        return Err("parameter pages are not at the end of flash".into());
    }
    uc.mmio_map(
        pb,
        plen,
        Some(
            move |uc: &mut Unicorn<'_, Machine>, off: u64, size: usize| {
                uc.get_data().flash.read_data((pb + off) as u32, size)
            },
        ),
        Some(
            move |uc: &mut Unicorn<'_, Machine>, off: u64, size: usize, v: u64| {
                let a = (pb + off) as u32;
                uc.get_data_mut().flash_store(a, size, v);
                stop_if_needed(uc);
            },
        ),
    )
    .map_err(|e| format!("map parameter pages: {e:?}"))?;
    let sram = HostMem::new(chip.sram_base, chip.sram_len as usize);
    // SAFETY: as for the code flash
    unsafe {
        uc.mem_map_ptr(
            chip.sram_base as u64,
            chip.sram_len as u64,
            Prot::READ | Prot::WRITE,
            sram.ptr().cast(),
        )
    }
    .map_err(|e| format!("map SRAM: {e:?}"))?;
    uc.get_data_mut().code = Some(code);
    uc.get_data_mut().sram = Some(sram);
    // every peripheral address: the model answers or names the fault
    for (base, len) in [(0x4000_0000u64, 0x2000_0000u64), (0xE000_0000, 0x10_0000)] {
        uc.mmio_map(
            base,
            len,
            Some(
                move |uc: &mut Unicorn<'_, Machine>, off: u64, size: usize| {
                    let a = (base + off) as u32;
                    let m = uc.get_data_mut();
                    if !a.is_multiple_of(size as u32) {
                        m.fail(format!(
                            "unaligned {size}-byte read of peripheral address {a:#010x}"
                        ));
                        stop_if_needed(uc);
                        return 0;
                    }
                    let v = m.read(a, size);
                    stop_if_needed(uc);
                    v
                },
            ),
            Some(
                move |uc: &mut Unicorn<'_, Machine>, off: u64, size: usize, v: u64| {
                    let a = (base + off) as u32;
                    let m = uc.get_data_mut();
                    if !a.is_multiple_of(size as u32) {
                        m.fail(format!(
                            "unaligned {size}-byte write of {v:#x} to peripheral address {a:#010x}"
                        ));
                    } else {
                        m.write(a, size, v);
                    }
                    stop_if_needed(uc);
                },
            ),
        )
        .map_err(|e| format!("map peripherals: {e:?}"))?;
    }
    for (addr, data) in image.load_segments()? {
        let end = addr as u64 + data.len() as u64;
        if (addr as u64) < fb || end > pb {
            return Err(format!(
                "ELF segment {addr:#010x}..{end:#010x} lies outside this chip's code flash"
            ));
        }
        uc.mem_write(addr as u64, &data)
            .map_err(|e| format!("load {addr:#x}: {e:?}"))?;
    }
    install_hooks(&mut uc, image)?;
    Ok(uc)
}

/// Ends the slice at the next block when the model wants attention (a fault, or an
/// interrupt that may now be taken).
fn stop_if_needed(uc: &mut Unicorn<'_, Machine>) {
    // unicorn keeps PC exact only at block starts outside memory hooks
    // (which would slow every load and store): a peripheral fault names
    // the basic block the access is in
    if uc.get_data().fault.is_some() && uc.get_data().fault_pc.is_none() {
        let pc = uc.get_data().block_pc;
        let m = uc.get_data_mut();
        m.fault_pc = Some(pc);
        m.fault_in_block = true;
    }
    // not emu_stop here: stopping inside an access would replay the
    // instruction (and the access's side effects) when the slice resumes
    let m = uc.get_data_mut();
    m.pending_hint = m.scs.best_pending().is_some();
    m.recheck = true;
    if m.fault.is_some() || m.flash.cut {
        m.stop_soon = true;
    }
}

/// Instructions in a block of Thumb code: a halfword whose top five bits
/// are 0b11101, 0b11110 or 0b11111 starts a 32-bit instruction.
fn count_insns(code: &[u8]) -> u32 {
    let mut n = 0;
    let mut i = 0;
    while i + 1 < code.len() {
        let hw = u16::from_le_bytes([code[i], code[i + 1]]);
        i += if hw >> 11 >= 0b11101 { 4 } else { 2 };
        n += 1;
    }
    n
}

/// Whether a block of `n` instructions runs in the slice that has run
/// `done` of its `budget`: if it ends within the budget, or as the slice's
/// first block (which must make progress, however short the slice).
fn block_fits(done: u64, n: u64, budget: u64) -> bool {
    done == 0 || done + n <= budget
}

fn install_hooks(uc: &mut Uc, image: &Image) -> Result<(), String> {
    uc.add_block_hook(
        1,
        0,
        |uc: &mut Unicorn<'_, Machine>, addr: u64, size: u32| {
            let n = match uc.get_data().block_cache.get(&addr) {
                Some(&n) => n,
                None => {
                    let code = uc.mem_read_as_vec(addr, size as usize).unwrap_or_default();
                    let n = count_insns(&code);
                    uc.get_data_mut().block_cache.insert(addr, n);
                    n
                }
            };
            // A stop asked for here ends the slice before this block runs
            // (the slice resumes at its first instruction), so the block
            // is counted only when it is let run. It runs if it would
            // pass the slice's budget only as a slice's first block: else
            // a block longer than the time to the next event would be
            // stopped before, again and again, while the clock went on.
            let m = uc.get_data_mut();
            let fits = block_fits(m.slice_insns, u64::from(n), m.budget);
            if !fits || std::mem::take(&mut m.stop_soon) {
                let _ = uc.emu_stop();
                return;
            }
            if m.pending_hint {
                // an interrupt may be takeable now: the NVIC is asked again
                // when the masks changed (CPSIE, MSR BASEPRI) or a
                // peripheral access may have changed what is pending
                let primask = uc.reg_read(R::PRIMASK).unwrap_or(1) & 1 != 0;
                let basepri = uc.reg_read(R::BASEPRI).unwrap_or(0) as u8;
                let m = uc.get_data_mut();
                if m.recheck || m.last_masks != (primask, basepri) {
                    m.recheck = false;
                    m.last_masks = (primask, basepri);
                    if m.scs.take(primask, basepri).is_some() {
                        let _ = uc.emu_stop();
                        return;
                    }
                }
            }
            let m = uc.get_data_mut();
            m.slice_insns += u64::from(n);
            m.block_pc = addr as u32;
            if let Some(p) = m.profile.as_mut() {
                p.record(addr as u32, n);
            }
            if m.call_trace.is_some() {
                let t = m.now();
                if let Some(ct) = m.call_trace.as_mut() {
                    ct.block(t, addr as u32);
                }
            }
        },
    )
    .map_err(|e| format!("hook: {e:?}"))?;
    let segs = image.load_segments()?;
    for (op, wfe) in [(0xBF30u16, false), (0xBF20, true)] {
        for a in image.find_hint(op, &segs) {
            uc.add_code_hook(a, a, move |uc: &mut Unicorn<'_, Machine>, addr: u64, _| {
                uc.get_data_mut().events.sleep = Some(wfe);
                let _ = uc.reg_write(R::PC, (addr + 2) | 1);
                let _ = uc.emu_stop();
            })
            .map_err(|e| format!("hook: {e:?}"))?;
        }
    }
    for a in image.find_hint(0xBF40, &segs) {
        uc.add_code_hook(a, a, |uc: &mut Unicorn<'_, Machine>, _, _| {
            uc.get_data_mut().event = true
        })
        .map_err(|e| format!("hook: {e:?}"))?;
    }
    uc.add_mem_hook(
        HookType::MEM_INVALID,
        1,
        0,
        |uc: &mut Unicorn<'_, Machine>, kind: MemType, addr: u64, size: usize, _v: i64| {
            let m = uc.get_data_mut();
            if kind == MemType::FETCH_UNMAPPED && addr >= EXC_RETURN_BASE {
                m.events.exc_return = true;
            } else {
                m.events.bad_access = Some((kind, addr, size));
                let pc = uc.reg_read(R::PC).unwrap_or(0) as u32;
                uc.get_data_mut().fault_pc = Some(pc);
            }
            false
        },
    )
    .map_err(|e| format!("hook: {e:?}"))?;
    Ok(())
}

fn rd32(uc: &Uc, a: u32) -> Result<u32, String> {
    let mut b = [0u8; 4];
    uc.mem_read(a as u64, &mut b)
        .map_err(|_| format!("exception stack access at {a:#010x} outside SRAM"))?;
    Ok(u32::from_le_bytes(b))
}
fn wr32(uc: &mut Uc, a: u32, v: u32) -> Result<(), String> {
    uc.mem_write(a as u64, &v.to_le_bytes())
        .map_err(|_| format!("exception stack access at {a:#010x} outside SRAM (stack overflow)"))
}
fn reg(uc: &Uc, r: R) -> u32 {
    uc.reg_read(r).unwrap_or(0) as u32
}

const BASIC: [R; 5] = [R::R0, R::R1, R::R2, R::R3, R::R12];
/// The IT/ICI bits of EPSR (at the same places in CPSR).
const IT_BITS: u32 = 0x0600_FC00;
/// xPSR bits restored from a frame: N Z C V Q, IT[1:0], GE, IT[7:2].
const PSR_RESTORE: u32 = 0xF800_0000 | 0x0600_0000 | 0x000F_0000 | 0x0000_FC00;

/// Reset: SP and PC from the vector table at the flash origin.
pub fn reset(uc: &mut Uc) -> Result<u32, String> {
    let base = uc.get_data().chip.flash_base;
    let sp = rd32(uc, base)?;
    let pc = rd32(uc, base + 4)?;
    for (r, v) in [
        (R::CONTROL, 0),
        (R::PRIMASK, 0),
        (R::BASEPRI, 0),
        (R::LR, 0xFFFF_FFFF),
    ] {
        uc.reg_write(r, v).map_err(|e| format!("{e:?}"))?;
    }
    uc.reg_write(R::MSP, sp as u64)
        .map_err(|e| format!("{e:?}"))?;
    uc.reg_write(R::SP, sp as u64)
        .map_err(|e| format!("{e:?}"))?;
    Ok(pc)
}

/// Exception entry: stacks the context on the main stack and returns the
/// handler's address (B1.5.6).
pub fn enter(uc: &mut Uc, e: usize, pc: u32) -> Result<u32, String> {
    let control = reg(uc, R::CONTROL);
    if control & 2 != 0 {
        return Err("process stack (CONTROL.SPSEL) in use: not modelled".into());
    }
    let m = uc.get_data();
    let fpca = m.chip.has_fpu && control & 4 != 0;
    let handler_mode = !m.scs.active.is_empty();
    let ipsr = m.scs.ipsr();
    let stkalign = m.scs.stkalign();
    let vtor = m.scs.vtor;
    let sp = reg(uc, R::SP);
    let size = if fpca { 0x68 } else { 0x20 };
    let align = stkalign && sp & 4 != 0;
    let frame = (sp - size) & if align { !4 } else { !0 };
    let cpsr = reg(uc, R::CPSR);
    let apsr = reg(uc, R::XPSR) & 0xF80F_0000;
    // the IT bits sit at the same places in CPSR and xPSR
    let xpsr = apsr | (cpsr & IT_BITS) | (1 << 24) | ((align as u32) << 9) | ipsr;
    let vals = [
        reg(uc, R::R0),
        reg(uc, R::R1),
        reg(uc, R::R2),
        reg(uc, R::R3),
        reg(uc, R::R12),
        reg(uc, R::LR),
        pc,
        xpsr,
    ];
    for (i, v) in vals.iter().enumerate() {
        wr32(uc, frame + 4 * i as u32, *v)?;
    }
    if fpca {
        for i in 0..16 {
            let s = reg(uc, fp_reg(i));
            wr32(uc, frame + 0x20 + 4 * i as u32, s)?;
        }
        let fpscr = reg(uc, R::FPSCR);
        wr32(uc, frame + 0x60, fpscr)?;
        uc.reg_write(R::CONTROL, (control & !4) as u64)
            .map_err(|e| format!("{e:?}"))?;
    }
    let mut exc_return: u32 = if handler_mode {
        0xFFFF_FFF1
    } else {
        0xFFFF_FFF9
    };
    if fpca {
        exc_return &= !0x10;
    }
    uc.reg_write(R::SP, frame as u64)
        .map_err(|e| format!("{e:?}"))?;
    // the handler starts outside any IT block (EPSR.IT = 0, B1.5.6): the
    // interrupted block's remaining conditions are in the stacked xPSR
    // only. unicorn keeps them in its own state and would otherwise apply
    // them to the handler's first instructions
    uc.reg_write(R::CPSR, (cpsr & !IT_BITS) as u64)
        .map_err(|e| format!("{e:?}"))?;
    uc.reg_write(R::LR, exc_return as u64)
        .map_err(|e| format!("{e:?}"))?;
    // the boot memory (main flash, BOOT0 low) is aliased at 0 (RM0440 §2.6,
    // RM0008 §3.4), where VTOR points after reset
    let chip = uc.get_data().chip;
    let table = if vtor < chip.flash_len {
        chip.flash_base + vtor
    } else {
        vtor
    };
    let handler = rd32(uc, table + 4 * e as u32)?;
    let m = uc.get_data_mut();
    m.scs.enter(e);
    m.event = true;
    m.clock.run_cycles(ENTRY_CYCLES);
    Ok(handler)
}

fn fp_reg(i: usize) -> R {
    [
        R::S0,
        R::S1,
        R::S2,
        R::S3,
        R::S4,
        R::S5,
        R::S6,
        R::S7,
        R::S8,
        R::S9,
        R::S10,
        R::S11,
        R::S12,
        R::S13,
        R::S14,
        R::S15,
    ][i]
}

/// Exception return through `exc` (the EXC_RETURN value): unstacks the
/// frame and returns the address to resume at (B1.5.8).
pub fn exit(uc: &mut Uc, exc: u32) -> Result<u32, String> {
    if exc & 4 != 0 {
        return Err(format!(
            "EXC_RETURN {exc:#010x} returns to the process stack: not modelled"
        ));
    }
    let to_thread = exc & 8 != 0;
    let m = uc.get_data_mut();
    let Some(_) = m.scs.exit() else {
        return Err(format!("EXC_RETURN {exc:#010x} with no exception active"));
    };
    if to_thread != m.scs.active.is_empty() {
        return Err(format!(
            "EXC_RETURN {exc:#010x} does not match the nesting of active exceptions"
        ));
    }
    m.event = true;
    m.clock.run_cycles(RETURN_CYCLES);
    let extended = exc & 0x10 == 0;
    let sp = reg(uc, R::SP);
    let mut v = [0u32; 8];
    for (i, x) in v.iter_mut().enumerate() {
        *x = rd32(uc, sp + 4 * i as u32)?;
    }
    for (i, r) in BASIC.iter().enumerate() {
        uc.reg_write(*r, v[i] as u64)
            .map_err(|e| format!("{e:?}"))?;
    }
    uc.reg_write(R::LR, v[5] as u64)
        .map_err(|e| format!("{e:?}"))?;
    let control = reg(uc, R::CONTROL);
    if extended {
        for i in 0..16 {
            let s = rd32(uc, sp + 0x20 + 4 * i as u32)?;
            uc.reg_write(fp_reg(i), s as u64)
                .map_err(|e| format!("{e:?}"))?;
        }
        let fpscr = rd32(uc, sp + 0x60)?;
        uc.reg_write(R::FPSCR, fpscr as u64)
            .map_err(|e| format!("{e:?}"))?;
        uc.reg_write(R::CONTROL, (control | 4) as u64)
            .map_err(|e| format!("{e:?}"))?;
    } else if control & 4 != 0 {
        uc.reg_write(R::CONTROL, (control & !4) as u64)
            .map_err(|e| format!("{e:?}"))?;
    }
    let xpsr = v[7];
    let size = if extended { 0x68 } else { 0x20 };
    let new_sp = sp + size + if xpsr & (1 << 9) != 0 { 4 } else { 0 };
    uc.reg_write(R::SP, new_sp as u64)
        .map_err(|e| format!("{e:?}"))?;
    let cpsr = reg(uc, R::CPSR);
    uc.reg_write(
        R::CPSR,
        ((cpsr & !PSR_RESTORE) | (xpsr & PSR_RESTORE)) as u64,
    )
    .map_err(|e| format!("{e:?}"))?;
    Ok(v[6])
}

#[cfg(test)]
mod tests {
    use super::block_fits;

    /// A block runs where it ends within the slice's budget; one that would
    /// pass it waits for the next slice, where it runs first even if it is
    /// longer than that slice's whole budget (a slice shorter than a block
    /// then still makes progress instead of stopping before it forever).
    #[test]
    fn a_block_runs_within_the_budget_or_first() {
        assert!(block_fits(0, 10, 100));
        assert!(block_fits(90, 10, 100));
        assert!(!block_fits(91, 10, 100));
        assert!(block_fits(0, 200, 100));
        assert!(block_fits(0, 200, 1));
        assert!(!block_fits(801, 200, 1000));
    }
}
