//! The commissioning master: this program as a Modbus master of a real
//! drive (or of any drive running this firmware: fw-sim, the virtual
//! drive), over a serial port or Modbus TCP.
//!
//! - `commission`: the commissioning page, backed by Modbus requests
//!   (`page.rs`);
//! - `scan`: every drive on the line (`scan.rs`);
//! - `params save` / `params restore`: PA0..PA59 to a file and back
//!   (`params.rs`, the file format in `params_file.rs`).
//!
//! Files: `cli.rs` (flags) → `serial.rs` / `tcp.rs` (the link) → this
//! file (requests and their failures) → the commands.

mod cli;
mod page;
mod params;
mod params_file;
mod scan;
mod serial;
mod status;
mod tally;
mod tcp;

use std::fmt;
use std::io;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use super::registers::{FORMATS, PA_BASE};
use super::web::{parse_reply, Answer, Pdu};
use modbus_drive::rtu::{CharFormat, LineConfig};

pub use cli::{is_tool, parse, Tool, HELP};
use tally::Tally;

/// Baud and character format of a serial line (PA52 / PA53 values).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LineSpec {
    pub baud: u32,
    /// PA53: 0 8N1, 1 8E1, 2 8O1, 3 8N2.
    pub format: u16,
}

impl LineSpec {
    /// The drive's default line (SPEC §1).
    pub const DEFAULT: Self = Self {
        baud: 115_200,
        format: 0,
    };

    /// From PA52 / PA53 values.
    pub fn from_pa(baud: u16, format: u16) -> Option<Self> {
        let line = LineConfig::from_params(baud, format)?;
        Some(Self {
            baud: line.baud(),
            format,
        })
    }

    fn bits_per_char(self) -> u32 {
        CharFormat::from_pa53(self.format).map_or(11, CharFormat::bits_per_char)
    }

    /// Time on the wire of `bytes` characters.
    pub fn time_of(self, bytes: usize) -> Duration {
        Duration::from_micros(
            u64::from(self.bits_per_char()) * bytes as u64 * 1_000_000 / u64::from(self.baud),
        )
    }

    /// t3.5 (SPEC §1: fixed 1750 µs above 19200 baud).
    pub fn t35(self) -> Duration {
        if self.baud > 19_200 {
            Duration::from_micros(1750)
        } else {
            Duration::from_micros(
                35 * u64::from(self.bits_per_char()) * 100_000 / u64::from(self.baud),
            )
        }
    }
}

impl fmt::Display for LineSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} {}",
            self.baud,
            FORMATS.get(usize::from(self.format)).unwrap_or(&"?")
        )
    }
}

/// Where the drive is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Endpoint {
    Serial { path: PathBuf, line: LineSpec },
    Tcp(String),
}

impl Endpoint {
    /// The reply wait unless `--timeout` says otherwise: on TCP longer
    /// than a gateway's own wait for its serial line (commonly 1 s), so
    /// that its "target failed to respond" arrives as the answer.
    pub fn default_timeout(&self) -> Duration {
        match self {
            Self::Serial { .. } => Duration::from_millis(300),
            Self::Tcp(_) => Duration::from_millis(1500),
        }
    }
}

/// A byte link that carries one request and its reply.
pub trait Link {
    /// The bytes found waiting before the last request, or before its
    /// reply, and discarded (a late reply to the request before, or other
    /// traffic).
    fn stale(&self) -> &[u8] {
        &[]
    }
    /// Puts a new baud / format in force (after a drive changed its own).
    fn set_line(&mut self, line: LineSpec) -> io::Result<()>;
    /// Sends `pdu` to `unit`; returns the request as sent and the reply as
    /// received (empty: none within `timeout` after the request left).
    fn exchange(
        &mut self,
        unit: u8,
        pdu: &Pdu,
        timeout: Duration,
    ) -> io::Result<(Vec<u8>, Vec<u8>)>;
}

/// Why a request got no usable answer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Failure {
    /// The drive refused it: code, and the request frame.
    Exception { code: u8, request: Vec<u8> },
    /// No answer, or not an answer to it; with the frames.
    NoAnswer {
        why: String,
        request: Vec<u8>,
        reply: Vec<u8>,
    },
}

impl fmt::Display for Failure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Exception { code, request } => {
                write!(f, "exception {code}; request {}", hex(request))
            }
            Self::NoAnswer {
                why,
                request,
                reply,
            } if reply.is_empty() => {
                write!(f, "{why}; request {}", hex(request))
            }
            Self::NoAnswer {
                why,
                request,
                reply,
            } => {
                write!(f, "{why}; request {}, reply {}", hex(request), hex(reply))
            }
        }
    }
}

pub fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// A Modbus master on one link, to one drive address at a time. The link
/// is opened on first use and again after it failed, so a drive that comes
/// back (an adapter plugged in again, a restarted runner) is found again.
pub struct Master {
    endpoint: Endpoint,
    link: Option<Box<dyn Link + Send>>,
    pub unit: u8,
    pub timeout: Duration,
    /// Reopen the port after [`REOPEN_AFTER_SILENT`] silent requests (not
    /// in a scan, where silence is the rule).
    pub reopen_on_silence: bool,
    /// Requests in a row that got no reply.
    silent: u32,
    tally: Tally,
}

/// Silent requests in a row after which the link is reopened (a port that
/// was replaced under the same name answers only once reopened).
const REOPEN_AFTER_SILENT: u32 = 3;

impl Master {
    pub fn new(endpoint: Endpoint, unit: u8, timeout: Duration) -> Self {
        Self {
            endpoint,
            link: None,
            unit,
            timeout,
            reopen_on_silence: true,
            silent: 0,
            tally: Tally::default(),
        }
    }

    pub fn describe(&self) -> String {
        match &self.endpoint {
            Endpoint::Serial { path, line } => format!("{} at {line}", path.display()),
            Endpoint::Tcp(peer) => format!("Modbus TCP {peer}"),
        }
    }

    /// Changes baud / format of the serial line (no effect on TCP).
    pub fn set_line(&mut self, new: LineSpec) -> io::Result<()> {
        if let Endpoint::Serial { line, .. } = &mut self.endpoint {
            *line = new;
            if let Some(l) = &mut self.link {
                l.set_line(new)?;
            }
        }
        Ok(())
    }

    fn link(&mut self) -> io::Result<&mut Box<dyn Link + Send>> {
        if self.link.is_none() {
            let l: Box<dyn Link + Send> = match &self.endpoint {
                Endpoint::Serial { path, line } => Box::new(serial::Serial::open(path, *line)?),
                Endpoint::Tcp(peer) => Box::new(tcp::Tcp::connect(peer)?),
            };
            self.link = Some(l);
        }
        Ok(self.link.as_mut().expect("opened above"))
    }

    /// The requests sent on this master and what came back.
    pub fn tally(&self) -> &Tally {
        &self.tally
    }

    /// See [`Link::stale`].
    pub fn stale(&self) -> &[u8] {
        self.link.as_ref().map_or(&[], |l| l.stale())
    }

    /// One request: the frame as sent, the reply frame as received, and
    /// the answer or why there is none.
    pub fn exchange(&mut self, pdu: &Pdu) -> (Vec<u8>, Vec<u8>, Result<Answer, String>) {
        let unit = self.unit;
        let timeout = self.timeout;
        let tcp = matches!(self.endpoint, Endpoint::Tcp(_));
        let result = self.link().and_then(|l| l.exchange(unit, pdu, timeout));
        match result {
            Err(e) => {
                self.link = None;
                let (what, sent) = if tcp {
                    (format!("link lost: {e}"), Vec::new())
                } else {
                    (format!("line lost: {e}"), pdu.frame(unit))
                };
                (sent, Vec::new(), Err(what))
            }
            Ok((request, reply)) if reply.is_empty() => {
                self.silent += 1;
                if self.reopen_on_silence && self.silent >= REOPEN_AFTER_SILENT {
                    self.link = None;
                    self.silent = 0;
                }
                self.tally.count(&reply, &Answer::Silent, !tcp);
                let why = format!("no reply within {} ms", timeout.as_millis());
                (request, reply, Err(why))
            }
            Ok((request, reply)) => {
                self.silent = 0;
                let answer = if tcp {
                    // the PDU after the MBAP header, checked as an RTU reply
                    match reply.get(7..) {
                        Some(p) if !p.is_empty() => {
                            parse_reply(unit, pdu, &Pdu(p.to_vec()).frame(reply[6]))
                        }
                        _ => Answer::Malformed(reply.clone()),
                    }
                } else {
                    parse_reply(unit, pdu, &reply)
                };
                self.tally.count(&reply, &answer, !tcp);
                (request, reply, Ok(answer))
            }
        }
    }

    /// A request whose normal answer's PDU is returned.
    pub fn request(&mut self, pdu: &Pdu) -> Result<Vec<u8>, Failure> {
        let (request, reply, answer) = self.exchange(pdu);
        match answer {
            Ok(Answer::Ok(p)) => Ok(p),
            Ok(Answer::Exception(code)) => Err(Failure::Exception { code, request }),
            Ok(Answer::Silent) => Err(Failure::NoAnswer {
                why: "no reply".into(),
                request,
                reply,
            }),
            Ok(Answer::Malformed(_)) => Err(Failure::NoAnswer {
                why: "a reply that does not answer the request".into(),
                request,
                reply,
            }),
            Err(why) => Err(Failure::NoAnswer {
                why,
                request,
                reply,
            }),
        }
    }

    /// 0x03 of `quantity` words at `start`.
    pub fn read(&mut self, start: u16, quantity: u16) -> Result<Vec<u16>, Failure> {
        let pdu = Pdu::read(start, quantity);
        let reply = self.request(&pdu)?;
        let words: Vec<u16> = reply
            .get(2..)
            .unwrap_or(&[])
            .chunks_exact(2)
            .map(|c| u16::from_be_bytes([c[0], c[1]]))
            .collect();
        if words.len() != usize::from(quantity) {
            return Err(Failure::NoAnswer {
                why: format!("{} words for {quantity}", words.len()),
                request: pdu.frame(self.unit),
                reply,
            });
        }
        Ok(words)
    }

    /// 0x06 of one word.
    pub fn write(&mut self, address: u16, value: u16) -> Result<(), Failure> {
        self.request(&Pdu::write_single(address, value)).map(|_| ())
    }

    /// 0x10 of `words` from `start`.
    pub fn write_words(&mut self, start: u16, words: &[u16]) -> Result<(), Failure> {
        self.request(&Pdu::write_multiple(start, words)).map(|_| ())
    }

    /// Diagnostics 0x08 sub-function `sub` with data 0: the value returned.
    pub fn diagnostic(&mut self, sub: u16) -> Result<u16, Failure> {
        let mut v = vec![0x08];
        v.extend_from_slice(&sub.to_be_bytes());
        v.extend_from_slice(&[0, 0]);
        let reply = self.request(&Pdu(v))?;
        Ok(reply
            .get(3..5)
            .map_or(0, |b| u16::from_be_bytes([b[0], b[1]])))
    }

    /// PA0..PA59 in one read.
    pub fn read_pas(&mut self) -> Result<Vec<u16>, Failure> {
        self.read(PA_BASE, super::registers::PA_COUNT as u16)
    }
}

/// Runs a master tool; the exit code says how it went.
pub fn main(tool: Tool) -> ExitCode {
    let result = match tool {
        Tool::Commission(o) => page::run(o),
        Tool::Scan(o) => scan::run(&o),
        Tool::Save(o) => params::save(o),
        Tool::Restore(o) => params::restore(o),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("modbus-drive: {e}");
            ExitCode::from(1)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_times_follow_spec_1() {
        let l = LineSpec::from_pa(1, 1).unwrap();
        assert_eq!(l.to_string(), "19200 8E1");
        // 11 bits a character at 19200: t3.5 ≈ 2005 µs.
        assert_eq!(l.t35(), Duration::from_micros(2005));
        assert_eq!(LineSpec::DEFAULT.t35(), Duration::from_micros(1750));
        assert!(LineSpec::from_pa(5, 0).is_none());
        assert!(LineSpec::from_pa(0, 4).is_none());
    }
}
