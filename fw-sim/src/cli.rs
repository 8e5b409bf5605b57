//! Command line of the runner: the board, the firmware image and the same
//! line and axis options as the virtual drive.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::chip::Kind;
use crate::machine::Switches;
use crate::motor::MotorOptions;

pub const USAGE: &str = "\
usage: fw-sim [--board g431|f103] [--elf FILE] [--tcp HOST:PORT]... [--modbus-tcp HOST:PORT]...
              [--pty-link PATH]
              [--trace-steps FILE] [--trace-line FILE] [--trace-pins FILE] [--trace-calls FILE] [--stats FILE] [--profile FILE] [--noise KIND@N,...] [--state FILE] [--power-cut N] [--cw-limit STEPS] [--ccw-limit STEPS]
              [--home-switch FROM:TO] [--write-protect] [--run-for SECONDS] [--quiet]
              [--encoder] [--encoder-counts N] [--steps-per-rev N] [--stall-at STEPS]
              [--slip STEPS@POS] [--encoder-noise COUNTS]

Runs the unmodified firmware image of a board on an emulated STM32.
  --board       g431 (STM32G431CB, default) or f103 (STM32F103C8)
  --elf         firmware ELF to run; default: build it (cargo fw / cargo fw-f103)
  --tcp         raw RTU bytes over TCP (as the virtual drive's --tcp)
  --modbus-tcp  Modbus TCP (MBAP) masters, through a TCP-to-RTU gateway: the
                unit identifier is the slave address (repeatable)
  --pty-link    a pseudo-terminal, linked at PATH
  --trace-steps CSV of every step pulse: time_ns,dir,width_ns
  --trace-line  CSV of the line: time_ns,event (rx, tx, de),value
  --trace-pins  CSV of ENABLE, BRAKE, STEP, DE: time_ns,cycles since reset,pin,state (0, 1, af, z)
  --trace-calls CSV of which firmware function runs when: time_ns,function, a
                line each time another one starts (large: for short runs)
  --noise       line faults on received characters, KIND@N[,KIND@N...]: KIND
                parity, framing, noise or break on the N-th character from
                the master (counted from 1 since the start)
  --power-cut N the supply fails as the N-th flash program or erase starts:
                the firmware restarts from the --state file (SRAM lost)
  --profile     rewritten with --stats: instructions per firmware function
                since reset, most first (`insns name` lines)
  --stats       rewritten every 50 ms (wall): emulated time_ns, busy and
                sleeping core cycles, step pulses, and the bytes at the
                stack's far end never written since power-on
  --state       file holding the parameter flash pages (kept across runs)
  --cw-limit / --ccw-limit / --home-switch: switch positions in steps
  --write-protect the parameter pages are write-protected (as by the option
                bytes): erase and program set WRPERR / WRPRTERR, change nothing
  --run-for     stop after this much emulated time (exit 0)
  --quiet       do not print the firmware's defmt log
  --encoder     a quadrature encoder on the motor, A on PB6 and B on PB7
                (TIM4_CH1/CH2), driven by the STEP pulses; the firmware reads
                it once its PA17 is set (set PA17 to --encoder-counts)
  --encoder-counts N  counts per revolution after x4 decoding [4000]
  --steps-per-rev N   motor steps per revolution (the firmware's PA10) [10000]
  --stall-at STEPS    the motor stalls where the steps reach STEPS (once; the
                stall ends when step output stops). Implies --encoder
  --slip STEPS@POS    the motor loses STEPS steps once where the steps pass
                POS. Implies --encoder
  --encoder-noise COUNTS  the shaft vibrates by up to +-COUNTS counts (a new
                value every 250 us). Implies --encoder";

/// A fault the line puts on one received character (the USART's PE, FE,
/// NE flags; a break is a character of zeros without a stop bit).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LineFault {
    Parity,
    Framing,
    Noise,
    Break,
}

pub struct Args {
    pub board: Kind,
    pub elf: Option<PathBuf>,
    pub tcp: Vec<SocketAddr>,
    pub modbus_tcp: Vec<SocketAddr>,
    pub pty_link: Option<PathBuf>,
    pub trace_steps: Option<PathBuf>,
    pub trace_line: Option<PathBuf>,
    pub trace_pins: Option<PathBuf>,
    pub trace_calls: Option<PathBuf>,
    pub stats: Option<PathBuf>,
    pub profile: Option<PathBuf>,
    /// Line faults: (1-based index of the received character, kind).
    pub noise: Vec<(u64, LineFault)>,
    pub power_cut: Option<u64>,
    pub write_protect: bool,
    pub state: Option<PathBuf>,
    pub switches: Switches,
    pub run_for_ps: Option<u64>,
    pub quiet: bool,
    /// `--encoder` and the flags that imply it.
    pub motor: Option<MotorOptions>,
}

fn num<T: std::str::FromStr>(flag: &str, v: &str) -> Result<T, String> {
    v.parse().map_err(|_| format!("{flag}: not a number: {v}"))
}

impl Args {
    pub fn parse(argv: impl Iterator<Item = String>) -> Result<Self, String> {
        let mut a = Args {
            board: Kind::G431,
            elf: None,
            tcp: Vec::new(),
            modbus_tcp: Vec::new(),
            pty_link: None,
            trace_steps: None,
            trace_line: None,
            trace_pins: None,
            trace_calls: None,
            stats: None,
            profile: None,
            noise: Vec::new(),
            power_cut: None,
            write_protect: false,
            state: None,
            switches: Switches::default(),
            run_for_ps: None,
            quiet: false,
            motor: None,
        };
        let mut it = argv.peekable();
        while let Some(flag) = it.next() {
            if flag == "--" {
                continue;
            }
            if flag == "--help" || flag == "-h" {
                return Err(USAGE.into());
            }
            if flag == "--quiet" {
                a.quiet = true;
                continue;
            }
            if flag == "--encoder" {
                a.motor.get_or_insert_with(Default::default);
                continue;
            }
            if flag == "--write-protect" {
                a.write_protect = true;
                continue;
            }
            let v = it
                .next()
                .ok_or_else(|| format!("{flag} needs a value\n{USAGE}"))?;
            match flag.as_str() {
                "--board" => {
                    a.board = match v.as_str() {
                        "g431" => Kind::G431,
                        "f103" => Kind::F103,
                        _ => return Err(format!("--board: g431 or f103, not {v}")),
                    }
                }
                "--elf" => a.elf = Some(v.into()),
                "--tcp" => a.tcp.push(
                    v.parse()
                        .map_err(|_| format!("--tcp: not HOST:PORT: {v}"))?,
                ),
                "--modbus-tcp" => a.modbus_tcp.push(
                    v.parse()
                        .map_err(|_| format!("--modbus-tcp: not HOST:PORT: {v}"))?,
                ),
                "--pty-link" => a.pty_link = Some(v.into()),
                "--trace-steps" => a.trace_steps = Some(v.into()),
                "--trace-line" => a.trace_line = Some(v.into()),
                "--trace-pins" => a.trace_pins = Some(v.into()),
                "--trace-calls" => a.trace_calls = Some(v.into()),
                "--stats" => a.stats = Some(v.into()),
                "--profile" => a.profile = Some(v.into()),
                "--power-cut" => a.power_cut = Some(num(&flag, &v)?),
                "--noise" => {
                    for item in v.split(',') {
                        let (kind, at) =
                            item.split_once('@').ok_or("--noise: KIND@N[,KIND@N...]")?;
                        let kind = match kind {
                            "parity" => LineFault::Parity,
                            "framing" => LineFault::Framing,
                            "noise" => LineFault::Noise,
                            "break" => LineFault::Break,
                            _ => {
                                return Err(format!(
                                    "--noise: parity, framing, noise or break, not {kind}"
                                ))
                            }
                        };
                        a.noise.push((num(&flag, at)?, kind));
                    }
                }
                "--state" => a.state = Some(v.into()),
                "--cw-limit" => a.switches.cw_limit = Some(num(&flag, &v)?),
                "--ccw-limit" => a.switches.ccw_limit = Some(num(&flag, &v)?),
                "--home-switch" => {
                    let (f, t) = v.split_once(':').ok_or("--home-switch: FROM:TO")?;
                    a.switches.home = Some((num(&flag, f)?, num(&flag, t)?));
                }
                "--encoder-counts" => {
                    let n: u32 = num(&flag, &v)?;
                    if n == 0 {
                        return Err("--encoder-counts: at least 1".into());
                    }
                    a.motor.get_or_insert_with(Default::default).counts_per_rev = n;
                }
                "--steps-per-rev" => {
                    let n: u32 = num(&flag, &v)?;
                    if n == 0 {
                        return Err("--steps-per-rev: at least 1".into());
                    }
                    a.motor.get_or_insert_with(Default::default).steps_per_rev = n;
                }
                "--stall-at" => {
                    a.motor.get_or_insert_with(Default::default).stall_at = Some(num(&flag, &v)?)
                }
                "--slip" => {
                    let (n, at) = v.split_once('@').ok_or("--slip: STEPS@POS")?;
                    a.motor.get_or_insert_with(Default::default).slip =
                        Some((num(&flag, n)?, num(&flag, at)?));
                }
                "--encoder-noise" => {
                    a.motor.get_or_insert_with(Default::default).noise_counts = num(&flag, &v)?
                }
                "--run-for" => a.run_for_ps = Some((num::<f64>(&flag, &v)? * 1e12) as u64),
                _ => return Err(format!("unknown option {flag}\n{USAGE}")),
            }
        }
        Ok(a)
    }
}

/// The board's release image, built with the repository's own alias.
pub fn build_firmware(board: Kind) -> Result<PathBuf, String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .ok_or("no repository root")?;
    let (alias, target) = match board {
        Kind::G431 => ("fw", "thumbv7em-none-eabihf"),
        Kind::F103 => ("fw-f103", "thumbv7m-none-eabi"),
    };
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let st = Command::new(cargo)
        .arg(alias)
        .arg("--quiet")
        .current_dir(root)
        // the outer `cargo run` of this runner must not steer the firmware build
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("CARGO_MANIFEST_DIR")
        .status()
        .map_err(|e| format!("cargo {alias}: {e}"))?;
    if !st.success() {
        return Err(format!("cargo {alias} failed"));
    }
    Ok(root
        .join("target")
        .join(target)
        .join("fw")
        .join("modbus-drive"))
}
