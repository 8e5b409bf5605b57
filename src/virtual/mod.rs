//! The virtual drive: the drive core in real time on a host, with
//! a simulated axis per drive, reachable by Modbus-RTU masters over a
//! pseudo-terminal and over TCP. Host glue only: framing, dispatch and drive
//! behaviour are the core's ([`modbus_drive::Device`]).
//!
//! Files, in the order a request travels: `cli.rs` (flags) → `transport.rs`
//! (pty / TCP byte streams) → `run.rs` (event loop: framing, replies,
//! control loop) → `console.rs` (status line, logs), `trace.rs` (CSV, SVG),
//! `flash.rs` (`--state` file as NOR flash), `web/` (`--web`, the
//! commissioning page). `master/`: the same program as a Modbus master of
//! a real drive (`commission`, `scan`, `params`).

mod cli;
mod console;
mod flash;
mod master;
mod registers;
mod run;
mod trace;
mod transport;
mod web;

use std::io::Write;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use cli::Command;

pub fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().is_some_and(|a| master::is_tool(a)) {
        return match master::parse(&args) {
            Ok(Some(tool)) => master::main(tool),
            Ok(None) => {
                print!("{}", master::HELP);
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("modbus-drive: {e}");
                ExitCode::from(2)
            }
        };
    }
    let opts = match cli::parse(args) {
        Ok(Command::Run(o)) => *o,
        Ok(Command::Help) => {
            print!("{}", cli::HELP);
            return ExitCode::SUCCESS;
        }
        Ok(Command::Version) => {
            println!("modbus-drive {}", env!("CARGO_PKG_VERSION"));
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("modbus-drive: {e}");
            return ExitCode::from(2);
        }
    };

    // Ctrl-C and SIGTERM only set a flag; the loop notices it within one
    // wake-up and exits through the normal path that writes trace and plot.
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        if let Err(e) = signal_hook::flag::register(sig, Arc::clone(&stop)) {
            eprintln!("modbus-drive: cannot handle signal {sig}: {e}");
            return ExitCode::from(1);
        }
    }

    let drive = match run::VirtualDrive::start(&opts) {
        Ok(d) => d,
        Err(run::StartError(msg)) => {
            eprintln!("modbus-drive: {msg}");
            return ExitCode::from(1);
        }
    };
    // Every transport accepts frames now (the pty exists, listeners are bound).
    let mut out = std::io::stdout().lock();
    if writeln!(out, "ready").and_then(|_| out.flush()).is_err() {
        // Nobody reads stdout; keep running, the transports work regardless.
    }
    drop(out);

    match drive.run(&stop) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("modbus-drive: {e}");
            ExitCode::from(1)
        }
    }
}
