//! fw-sim: runs a board's unmodified firmware ELF on an emulated STM32 and
//! connects its USART1 to TCP or a pseudo-terminal, like the virtual drive.
//! See docs/fw-sim.md.

mod call_trace;
mod chip;
mod cli;
mod clock;
mod cpu;
mod elf;
mod gateway;
mod interconnect;
mod line;
mod machine;
mod mem;
mod motor;
mod periph;
mod pin_trace;
mod profile;
mod rtt;
mod scs;
mod stack;
mod trace;

use std::cell::RefCell;
use std::io::Write;
use std::time::{Duration, Instant};

use unicorn_engine::RegisterARM as R;

use chip::{pins, Chip, Kind};
use cli::{Args, LineFault};
use cpu::Uc;
use elf::Image;
use line::Line;
use machine::Machine;
use periph::flash::Flash;
use periph::usart::RxChar;
use pin_trace::PinTrace;
use rtt::Rtt;
use trace::{LineTrace, StepTrace};

/// The longest slice of instructions between two looks at the line and the
/// interrupt controller.
const MAX_SLICE: u64 = 20_000;
/// How often (wall time) the line is polled while the core is busy.
const POLL_EVERY: Duration = Duration::from_millis(1);
/// How often (wall time) `--stats` is rewritten.
const STATS_EVERY: Duration = Duration::from_millis(50);

fn main() {
    let code = match run() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("fw-sim: {e}");
            2
        }
    };
    std::process::exit(code);
}

/// The parameter pages of each board (src/firmware/board_*.rs).
fn param_pages(kind: Kind) -> (u32, u32) {
    match kind {
        Kind::G431 => (0x1_F000, 0x1000),
        Kind::F103 => (0xF000, 0x1000),
    }
}

/// RCC_CSR reset flags (RM0440 / RM0008, the same bits on both chips).
const RSTF_PIN: u32 = 1 << 26;
const RSTF_SOFTWARE: u32 = 1 << 28;
const RSTF_IWDG: u32 = 1 << 29;

fn run() -> Result<i32, String> {
    let args = Args::parse(std::env::args().skip(1))?;
    let elf = match &args.elf {
        Some(p) => p.clone(),
        None => cli::build_firmware(args.board)?,
    };
    let bytes = std::fs::read(&elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let image = Image::load(bytes)?;
    let chip = Chip::new(args.board);
    let (poff, plen) = param_pages(args.board);
    let flash = Flash::new(
        chip.is_g4(),
        chip.flash_base,
        chip.flash_end(),
        chip.page,
        chip.flash_base + poff,
        plen,
        args.state.clone(),
        chip.t_prog_ps,
        chip.t_erase_ps,
    )
    .map_err(|e| format!("--state: {e}"))?;
    let trace = match &args.trace_steps {
        Some(p) => Some(StepTrace::create(p).map_err(|e| format!("{}: {e}", p.display()))?),
        None => None,
    };
    let line_trace = match &args.trace_line {
        Some(p) => Some(LineTrace::create(p).map_err(|e| format!("{}: {e}", p.display()))?),
        None => None,
    };
    let mut machine = Machine::new(chip, flash, args.switches, trace);
    if let Some(p) = &args.trace_pins {
        let brake = if chip.is_g4() {
            pins::BRAKE_G431
        } else {
            pins::BRAKE_F103
        };
        let de = if chip.is_g4() {
            pins::DE_G431
        } else {
            pins::DE_F103
        };
        let traced = [
            ("enable", pins::ENABLE),
            ("brake", brake),
            ("step", pins::STEP[0]),
            ("de", de),
        ];
        machine.pin_trace =
            Some(PinTrace::create(p, traced).map_err(|e| format!("{}: {e}", p.display()))?);
        machine.look_at_pins(0);
    }
    machine.flash.cut_at = args.power_cut;
    machine.flash.write_protected = args.write_protect;
    machine.motor = args.motor.map(motor::Motor::new);
    if args.profile.is_some() {
        machine.profile = Some(profile::Profile::default());
    }
    if let Some(p) = &args.trace_calls {
        machine.call_trace = Some(
            call_trace::CallTrace::create(p, image.symbols())
                .map_err(|e| format!("{}: {e}", p.display()))?,
        );
    }
    let mut uc = cpu::create(&image, machine)?;
    let rtt = if args.quiet {
        None
    } else {
        image.rtt.and_then(|cb| Rtt::new(&image.bytes, cb))
    };
    let line = Line::new(&args.tcp, &args.modbus_tcp, args.pty_link.as_ref())
        .map_err(|e| format!("line: {e}"))?;
    eprintln!("fw-sim: {} running {}", chip.name, elf.display());
    stack::paint(&mut uc)?;
    let pc = cpu::reset(&mut uc)?;
    let mut r = Runner {
        uc,
        image,
        rtt,
        line,
        pc,
        sleeping: None,
        ready: None,
        rx_tail: 0,
        last_poll: Instant::now(),
        run_for: args.run_for_ps,
        line_trace,
        noise: args.noise.clone(),
        rx_count: 0,
        stats: args.stats.clone(),
        profile: args.profile.clone(),
        last_stats: Instant::now(),
    };
    r.run()
}

struct Runner {
    uc: Uc,
    image: Image,
    rtt: Option<Rtt>,
    line: Line,
    pc: u32,
    /// Asleep in WFI (false) or WFE (true).
    sleeping: Option<bool>,
    /// Boot finished: (emulated time, wall time) then; emulated time is
    /// kept from running ahead of wall time after it.
    ready: Option<(u64, Instant)>,
    /// End of the last character queued on the RX wire.
    rx_tail: u64,
    last_poll: Instant,
    run_for: Option<u64>,
    line_trace: Option<LineTrace>,
    /// `--noise`: faults by received character index, and that count.
    noise: Vec<(u64, LineFault)>,
    rx_count: u64,
    stats: Option<std::path::PathBuf>,
    profile: Option<std::path::PathBuf>,
    last_stats: Instant,
}

impl Runner {
    fn m(&mut self) -> &mut Machine {
        self.uc.get_data_mut()
    }
    fn now(&self) -> u64 {
        self.uc.get_data().clock.now()
    }

    /// Emulated time that corresponds to wall time now (after boot).
    fn wall_now(&self) -> Option<u64> {
        self.ready
            .map(|(t0, w0)| t0 + w0.elapsed().as_nanos() as u64 * 1000)
    }

    fn run(&mut self) -> Result<i32, String> {
        loop {
            if let Some(msg) = self.m().fault.take() {
                return Ok(self.report(&msg));
            }
            let now = self.now();
            if self.uc.get_data().flash.cut {
                self.power_cycle(now)?;
                continue;
            }
            if self.uc.get_data().scs.reset_request || self.uc.get_data().iwdg.expired(now) {
                eprintln!("fw-sim: system reset at {} µs", now / 1_000_000);
                // RM0440 / RM0008 RCC_CSR: the cause's flag, and PINRSTF:
                // an internal reset drives NRST low too
                let cause = if self.uc.get_data().scs.reset_request {
                    RSTF_SOFTWARE
                } else {
                    RSTF_IWDG
                };
                self.m().reset_peripherals(Some(cause | RSTF_PIN));
                self.pc = cpu::reset(&mut self.uc)?;
                self.sleeping = None;
                continue;
            }
            if self.ready.is_none() && self.uc.get_data().line_ready() {
                self.ready = Some((now, Instant::now()));
                println!("ready");
                let _ = std::io::stdout().flush();
            }
            if self.run_for.is_some_and(|l| now >= l) {
                self.poll_rtt();
                return Ok(0);
            }
            if self.last_poll.elapsed() >= POLL_EVERY {
                self.input(Duration::ZERO);
            }
            let primask = self.uc.reg_read(R::PRIMASK).unwrap_or(1) & 1 != 0;
            let basepri = self.uc.reg_read(R::BASEPRI).unwrap_or(0) as u8;
            if let Some(e) = self.uc.get_data().scs.take(primask, basepri) {
                match cpu::enter(&mut self.uc, e, self.pc) {
                    Ok(h) => self.pc = h,
                    Err(msg) => return Ok(self.report(&msg)),
                }
                self.sleeping = None;
                continue;
            }
            if let Some(wfe) = self.sleeping {
                let m = self.m();
                let awake = if wfe {
                    std::mem::take(&mut m.event)
                } else {
                    m.scs.wakes(basepri)
                };
                if awake {
                    self.sleeping = None;
                } else {
                    self.idle()?;
                    continue;
                }
            }
            self.slice();
            self.after_slice();
        }
    }

    /// `--power-cut`: the supply failed as a flash operation started. The
    /// chip comes back from cold: SRAM cleared, every peripheral reset, the
    /// flash array as the file holds it; the line stays connected.
    fn power_cycle(&mut self, now: u64) -> Result<(), String> {
        let m = self.m();
        let n = m.flash.ops_started;
        m.flash.cut = false;
        m.flash.cut_at = None;
        eprintln!(
            "fw-sim: power cut as flash operation {n} started ({} µs): restarting",
            now / 1_000_000
        );
        m.reset_peripherals(None);
        let (base, len) = (m.chip.sram_base, m.chip.sram_len);
        self.uc
            .mem_write(base as u64, &vec![0; len as usize])
            .map_err(|e| format!("{e:?}"))?;
        stack::paint(&mut self.uc)?;
        self.pc = cpu::reset(&mut self.uc)?;
        self.sleeping = None;
        Ok(())
    }

    /// Runs instructions until the next peripheral event (at most
    /// MAX_SLICE), a WFI/WFE, an exception return or a fault.
    fn slice(&mut self) {
        let m = self.m();
        let budget = m
            .next_event()
            .map_or(MAX_SLICE, |t| m.clock.cycles_until(t))
            .clamp(1, MAX_SLICE);
        m.budget = budget;
        m.stop_soon = false;
        m.pending_hint = m.scs.best_pending().is_some();
        m.recheck = true;
        m.slice_insns = 0;
        m.events = Default::default();
        let res = self.uc.emu_start(self.pc as u64 | 1, 0, 0, 0);
        let m = self.m();
        let n = m.slice_insns;
        m.clock.run_cycles(n);
        m.slice_insns = 0;
        let ev = m.events;
        self.pc = self.uc.reg_read(R::PC).unwrap_or(0) as u32;
        // unicorn's core raises an internal exception for a branch into
        // 0xFFFF_xxxx (the EXC_RETURN range) in M profile
        if ev.exc_return || (res.is_err() && self.pc >= 0xFFFF_FF00) {
            let exc = self.pc | 1;
            match cpu::exit(&mut self.uc, exc) {
                Ok(pc) => self.pc = pc,
                Err(msg) => self.m().fail(msg),
            }
        } else if let Some((kind, addr, size)) = ev.bad_access {
            let what = format!("{kind:?}").to_lowercase().replace('_', " ");
            self.m().fail(format!(
                "{size}-byte {what} at {addr:#010x}: outside this chip's memories"
            ));
        } else if let Err(e) = res {
            let op = self
                .uc
                .mem_read_as_vec(self.pc as u64, 2)
                .unwrap_or_default();
            let msg = if op.len() == 2 && op[1] == 0xDE {
                "the firmware stopped on a UDF instruction (panic-probe after a panic, or a HardFault)".to_string()
            } else {
                format!("the CPU stopped ({e:?}): an instruction faulted (HardFault)")
            };
            self.m().fail(msg);
        }
        if let Some(wfe) = ev.sleep {
            self.sleeping = Some(wfe);
        }
    }

    /// `--stats`: a snapshot of the counters a measurement needs, written
    /// whole to a new file and renamed, so a reader never sees half of it.
    fn write_stats(&mut self) {
        if self.last_stats.elapsed() < STATS_EVERY {
            return;
        }
        self.last_stats = Instant::now();
        if let Some(ct) = self.uc.get_data_mut().call_trace.as_mut() {
            ct.flush();
        }
        if let (Some(path), Some(p)) = (&self.profile, &self.uc.get_data().profile) {
            p.write(&self.image, path);
        }
        let Some(path) = &self.stats else { return };
        let untouched = stack::untouched(&self.uc).unwrap_or(0);
        let m = self.uc.get_data();
        let text = format!(
            "time_ns {}\nbusy_cycles {}\nsleep_cycles {}\nsteps {}\nstack_untouched {}\n",
            m.clock.now() / 1000,
            m.clock.busy_cycles(),
            m.clock.sleep_cycles(),
            m.steps_total,
            untouched
        );
        let tmp = path.with_extension("tmp");
        if std::fs::write(&tmp, text).is_ok() {
            let _ = std::fs::rename(&tmp, path);
        }
    }

    fn after_slice(&mut self) {
        self.write_stats();
        let t = self.now();
        self.m().sync(t);
        self.output();
        self.poll_rtt();
        // never ahead of wall time once booted
        if let Some(w) = self.wall_now() {
            if t > w + 1_000_000_000 {
                self.input(Duration::from_nanos((t - w) / 1000));
            }
        }
    }

    /// Asleep with nothing to take: time jumps to the next event, at wall
    /// speed once booted (the line is watched meanwhile).
    fn idle(&mut self) -> Result<(), String> {
        let now = self.now();
        let next = self.uc.get_data().next_event();
        let next = match (next, self.run_for) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        match self.wall_now() {
            None => {
                let Some(t) = next else {
                    return Err("the firmware sleeps before it armed its receiver, with no event to wake it".into());
                };
                self.sleep_to(t.max(now));
            }
            Some(wall) => {
                if let Some(t) = next.filter(|&t| t <= wall) {
                    self.sleep_to(t.max(now));
                } else {
                    let wait = next.map_or(Duration::from_millis(200), |t| {
                        Duration::from_nanos((t - wall) / 1000)
                    });
                    let chunks = self.line.poll(wait);
                    let wall = self.wall_now().unwrap_or(now);
                    let t = next.map_or(wall, |n| n.min(wall)).max(now);
                    self.sleep_to(t);
                    self.queue(chunks);
                }
            }
        }
        self.output();
        Ok(())
    }

    fn sleep_to(&mut self, t: u64) {
        self.write_stats();
        let m = self.m();
        m.clock.sleep_until(t);
        m.sync(t);
    }

    /// Reads the line (waiting up to `wait`) and queues what came.
    fn input(&mut self, wait: Duration) {
        let chunks = self.line.poll(wait);
        self.queue(chunks);
        self.gateway();
    }

    /// Characters from the master onto the RX wire, back to back from now,
    /// each one character time long at the USART's current format.
    fn queue(&mut self, chunks: Vec<Vec<u8>>) {
        self.last_poll = Instant::now();
        let now = self.now();
        let m = self.uc.get_data_mut();
        let cps = m.usart.char_ps();
        for chunk in chunks {
            if cps == 0 {
                continue;
            }
            for b in chunk {
                let start = self.rx_tail.max(now);
                self.rx_tail = start + cps;
                self.rx_count += 1;
                let mut c = RxChar {
                    byte: b,
                    ..Default::default()
                };
                for &(_, f) in self.noise.iter().filter(|n| n.0 == self.rx_count) {
                    match f {
                        LineFault::Parity => c.parity_error = true,
                        LineFault::Framing => c.framing_error = true,
                        LineFault::Noise => c.noise = true,
                        LineFault::Break => c.brk = true,
                    }
                }
                m.usart.rx.push_back((self.rx_tail, c));
                if let Some(lt) = self.line_trace.as_mut() {
                    lt.event(self.rx_tail, "rx", b as u32);
                }
            }
        }
    }

    /// Characters that left the emulated TX wire while the driver was on.
    fn output(&mut self) {
        let m = self.uc.get_data_mut();
        if let Some(lt) = self.line_trace.as_mut() {
            for (t, level) in m.usart.de_edges.drain(..) {
                lt.event(t, "de", level as u32);
            }
            for c in &m.usart.tx_out {
                lt.event(c.0, "tx", c.2 as u32);
            }
        } else {
            m.usart.de_edges.clear();
        }
        let mut out = Vec::new();
        for (_, end, byte, driven) in m.usart.tx_out.drain(..) {
            if driven {
                out.push(byte);
                self.line.gateway.tx(byte, end);
            }
        }
        if !out.is_empty() {
            self.line.send(&out);
        }
        self.gateway();
    }

    /// `--modbus-tcp`: finishes the request on the line when its reply is
    /// complete or overdue, and puts the next one on the RX wire.
    fn gateway(&mut self) {
        let now = self.now();
        let t35 = self.uc.get_data().usart.t35_ps();
        self.line.gateway.tick(now, t35);
        if let Some(frame) = self.line.gateway.next_frame() {
            self.queue(vec![frame]);
            self.line.gateway.sent(self.rx_tail);
        }
    }

    fn poll_rtt(&mut self) {
        let Some(rtt) = self.rtt.as_mut() else { return };
        let uc = RefCell::new(&mut self.uc);
        rtt.poll(
            &mut |a, n| uc.borrow().mem_read_as_vec(a as u64, n).ok(),
            &mut |a, v| {
                let _ = uc.borrow_mut().mem_write(a as u64, &v.to_le_bytes());
            },
        );
    }

    /// Prints a fault with the firmware's registers named by symbol.
    fn report(&mut self, msg: &str) -> i32 {
        self.poll_rtt();
        let m = self.uc.get_data();
        let pc = m.fault_pc.unwrap_or(self.pc);
        let at = if m.fault_in_block {
            "in the basic block at "
        } else {
            ""
        };
        let lr = self.uc.reg_read(R::LR).unwrap_or(0) as u32;
        let sp = self.uc.reg_read(R::SP).unwrap_or(0) as u32;
        let t = m.clock.now();
        eprintln!("fw-sim: FAULT: {msg}");
        eprintln!("  pc {at}{pc:#010x} {}", self.image.symbol(pc));
        eprintln!("  lr {lr:#010x} {}", self.image.symbol(lr));
        eprintln!(
            "  sp {sp:#010x}, emulated time {}.{:06} s",
            t / 1_000_000_000_000,
            (t / 1_000_000) % 1_000_000
        );
        1
    }
}
