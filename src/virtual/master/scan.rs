//! `scan`: every drive on a serial line. At each baud and format tried,
//! each address 1..=247 is asked for PA2 (the firmware version) with a
//! short wait; a drive that answers is then read for its state, address
//! and line PAs. A drive found is not asked again at later line settings.
//!
//! A pseudo-terminal or a USB adapter talking to a converter carries no
//! baud: a drive behind one answers at every setting. So the line printed
//! is the one the drive itself holds (PA52/PA53), and the one it answered
//! at is added when they differ.

use std::io::Write;
use std::time::{Duration, Instant};

use super::cli::Scan;
use super::status::power_state;
use super::{Endpoint, LineSpec, Master};
use crate::virtual_drive::registers::{PA_ADDRESS, PA_BASE, PA_BAUD, PA_FIRMWARE, PA_FORMAT};

/// Reply wait beyond the frames' own time on the wire (the drive's
/// response delay PA56 defaults to 0).
/// Covers a USB adapter's latency timer too (an FTDI chip holds a short
/// reply up to 16 ms by default).
const MARGIN: Duration = Duration::from_millis(25);
const STATUSWORD: u16 = 0x6041;
/// PA2's reply (the link's wait starts once the request has left).
const REPLY_BYTES: usize = 7;

pub struct Found {
    pub address: u8,
    pub answered_at: LineSpec,
    pub line: Option<LineSpec>,
    pub firmware: u16,
    pub state: String,
}

pub fn run(o: &Scan) -> Result<(), String> {
    let started = Instant::now();
    let mut found: Vec<Found> = Vec::new();
    let mut m = Master::new(
        Endpoint::Serial {
            path: o.path.clone(),
            line: o.lines[0],
        },
        1,
        MARGIN,
    );
    m.reopen_on_silence = false;
    let stderr = std::io::stderr();
    for &line in &o.lines {
        m.set_line(line)
            .map_err(|e| format!("{}: {e}", o.path.display()))?;
        m.timeout = o
            .timeout
            .unwrap_or(line.time_of(REPLY_BYTES) + line.t35() * 2 + MARGIN);
        for address in 1..=247u8 {
            if address % 16 == 1 {
                let mut e = stderr.lock();
                let _ = write!(
                    e,
                    "\rscanning {line}: address {address:>3}/247, {} found ",
                    found.len()
                );
                let _ = e.flush();
            }
            if found.iter().any(|f| f.address == address) {
                continue;
            }
            m.unit = address;
            let probe = m.read(PA_BASE + PA_FIRMWARE as u16, 1);
            // An address asked before was silent but its reply came after
            // the wait, before or during this probe (a slow drive, a busy
            // host): ask it again, patiently.
            for late in repliers(m.stale()) {
                if late >= address || found.iter().any(|f| f.address == late) {
                    continue;
                }
                m.unit = late;
                let wait = m.timeout;
                m.timeout = wait * 4;
                if let Ok(fw) = m.read(PA_BASE + PA_FIRMWARE as u16, 1) {
                    found.push(report(details(&mut m, line, fw[0])));
                }
                m.timeout = wait;
                m.unit = address;
            }
            if let Ok(fw) = probe {
                found.push(report(details(&mut m, line, fw[0])));
            }
        }
    }
    eprintln!(
        "\rscan done: {} drive(s), {} line setting(s), {:.1} s",
        found.len(),
        o.lines.len(),
        started.elapsed().as_secs_f64()
    );
    if found.is_empty() {
        return Err("no drive answered".into());
    }
    Ok(())
}

/// The rest of what the scan prints of the drive at `m.unit`, which
/// answered PA2 = `firmware` at `line`.
fn details(m: &mut Master, line: LineSpec, firmware: u16) -> Found {
    let pas = m.read(PA_BASE + PA_ADDRESS as u16, 3).ok();
    let state = m
        .read(STATUSWORD, 1)
        .ok()
        .and_then(|sw| power_state(sw[0]))
        .map_or("?".into(), |s| format!("{s:?}"));
    Found {
        address: m.unit,
        answered_at: line,
        line: pas
            .and_then(|p| LineSpec::from_pa(p[PA_BAUD - PA_ADDRESS], p[PA_FORMAT - PA_ADDRESS])),
        firmware,
        state,
    }
}

fn report(f: Found) -> Found {
    eprintln!();
    println!("{}", describe(&f));
    f
}

/// The addresses of the reply frames (right CRC) inside `bytes`.
fn repliers(bytes: &[u8]) -> Vec<u8> {
    let mut out: Vec<u8> = Vec::new();
    for i in 0..bytes.len() {
        let b = &bytes[i..];
        let whole = (5..=b.len()).any(|n| modbus_drive::rtu::crc16(&b[..n]) == 0);
        if (1..=247).contains(&b[0]) && whole && !out.contains(&b[0]) {
            out.push(b[0]);
        }
    }
    out
}

pub fn describe(f: &Found) -> String {
    let line = match f.line {
        Some(l) if l == f.answered_at => l.to_string(),
        Some(l) => format!("{l} (answered at {})", f.answered_at),
        None => format!("{} (its PA52/PA53 unreadable)", f.answered_at),
    };
    format!(
        "address {:>3}  line {line}  firmware {}  state {}",
        f.address, f.firmware, f.state
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::virtual_drive::web::Pdu;

    #[test]
    fn late_replies_are_told_among_other_bytes() {
        let reply = Pdu(vec![0x03, 0x02, 0x1B, 0x94]).frame(16);
        let mut bytes = vec![0x00, 0x10, 0xFF];
        bytes.extend(&reply);
        assert_eq!(repliers(&bytes), [16]);
        // a frame cut short, or with a bad CRC, is no reply
        assert!(repliers(&reply[..reply.len() - 1]).is_empty());
        let mut bad = reply.clone();
        bad[3] ^= 1;
        assert!(repliers(&bad).is_empty());
        assert!(repliers(&[]).is_empty());
    }
}
