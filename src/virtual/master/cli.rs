//! Command line of the master tools: `commission`, `scan`, `params save`,
//! `params restore` (the first word picks the tool; the virtual drive's
//! own flags are `../cli.rs`).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use super::{Endpoint, LineSpec};
use crate::virtual_drive::registers::{bauds, FORMATS};

pub const HELP: &str = "\
modbus-drive as a Modbus master of a drive that runs this firmware (a real
board on a USB-RS485 adapter, fw-sim, or the virtual drive).

USAGE:
    modbus-drive commission LINK [--address N] --web ADDR:PORT [--web-token T]
    modbus-drive scan --serial PORT [--baud B|auto] [--format F] [--quick]
    modbus-drive params save LINK [--address N] FILE
    modbus-drive params restore LINK [--address N] [--yes] FILE

LINK (one of):
    --serial PORT            A serial port (/dev/ttyUSB0, a pseudo-terminal),
                             RTU at --baud and --format.
    --modbus-tcp-master HOST:PORT
                             Modbus TCP (a gateway, or a drive's Modbus TCP
                             port); the unit id is --address.

OPTIONS:
    --baud B                 9600, 19200, 38400, 57600, 115200 [default:
                             115200]; for scan also `auto` (every one).
    --format F               8N1, 8E1, 8O1, 8N2 [default: 8N1; scan: every
                             one unless given].
    --address N              The drive's address, 1..=247 [default: 1].
    --timeout MS             Longest wait for a reply [default: 300 on a
                             serial port, 1500 on TCP; scan: the line's
                             frame times and 25 ms].
    --web ADDR:PORT          commission: serve the page there (127.0.0.1:8080;
                             port 0 picks one, printed on stderr).
    --web-token TOKEN        commission: every request to the page needs
                             TOKEN (16+ of A-Z a-z 0-9 - _ . ~); bound
                             beyond loopback without it, a random one is
                             printed in the page's URL.
    --quick                  scan: the default line only (115200 8N1).
    --yes                    params restore: write the changes (without it
                             the differences are shown and nothing written).
    FILE                     params: a .toml or .json file.
";

pub struct Common {
    pub endpoint: Endpoint,
    pub address: u8,
    pub timeout: Option<Duration>,
}

pub struct Commission {
    pub common: Common,
    pub web: SocketAddr,
    pub web_token: Option<String>,
}

pub struct Scan {
    pub path: PathBuf,
    /// Lines to try, in order.
    pub lines: Vec<LineSpec>,
    pub timeout: Option<Duration>,
}

pub struct Params {
    pub common: Common,
    pub file: PathBuf,
    pub yes: bool,
}

pub enum Tool {
    Commission(Commission),
    Scan(Scan),
    Save(Params),
    Restore(Params),
}

/// A command-line word: a flag, or a value of its own (the file).
enum Arg {
    Flag(String),
    Value(PathBuf),
}

/// Whether `first` names a master tool.
pub fn is_tool(first: &str) -> bool {
    matches!(first, "commission" | "scan" | "params")
}

/// The tool and its options; `Ok(None)` for `--help`.
pub fn parse(args: &[String]) -> Result<Option<Tool>, String> {
    let mut it = args.iter();
    let tool = it.next().map(String::as_str).unwrap_or("");
    let tool = match tool {
        "params" => match it.next().map(String::as_str) {
            Some("save") => "save",
            Some("restore") => "restore",
            Some("--help" | "-h") => return Ok(None),
            _ => return Err("params: save or restore (see --help)".into()),
        },
        t => t,
    };
    let mut serial = None;
    let mut tcp = None;
    let mut baud: Option<String> = None;
    let mut format: Option<String> = None;
    let mut address = 1u8;
    let mut timeout = None;
    let mut web = None;
    let mut web_token = None;
    let mut quick = false;
    let mut yes = false;
    let mut file = None;
    let mut p = lexopt::Parser::from_args(it.cloned());
    while let Some(arg) = p.next().map_err(|e| e.to_string())? {
        // owned, so that the parser can be asked for the flag's value
        let arg = match arg {
            lexopt::Arg::Long(l) => Arg::Flag(format!("--{l}")),
            lexopt::Arg::Short(c) => Arg::Flag(format!("-{c}")),
            lexopt::Arg::Value(v) => Arg::Value(PathBuf::from(v)),
        };
        let mut value = |name: &str| -> Result<String, String> {
            p.value()
                .map(|v| v.to_string_lossy().into_owned())
                .map_err(|_| format!("{name} needs a value"))
        };
        match arg {
            Arg::Flag(f) if f == "-h" || f == "--help" => return Ok(None),
            Arg::Flag(f) if f == "--serial" => serial = Some(PathBuf::from(value("--serial")?)),
            Arg::Flag(f) if f == "--modbus-tcp-master" => tcp = Some(value("--modbus-tcp-master")?),
            Arg::Flag(f) if f == "--baud" => baud = Some(value("--baud")?),
            Arg::Flag(f) if f == "--format" => format = Some(value("--format")?.to_uppercase()),
            Arg::Flag(f) if f == "--address" => {
                let v = value("--address")?;
                address = v
                    .parse()
                    .ok()
                    .filter(|a| (1..=247).contains(a))
                    .ok_or(format!("--address {v}: 1..=247"))?;
            }
            Arg::Flag(f) if f == "--timeout" => {
                let v = value("--timeout")?;
                let ms: u64 = v
                    .parse()
                    .ok()
                    .filter(|&ms| (1..=10_000).contains(&ms))
                    .ok_or(format!("--timeout {v}: 1..=10000 ms"))?;
                timeout = Some(Duration::from_millis(ms));
            }
            Arg::Flag(f) if f == "--web" => {
                let v = value("--web")?;
                web = Some(v.parse().map_err(|_| format!("--web {v}: not ADDR:PORT"))?);
            }
            Arg::Flag(f) if f == "--web-token" => {
                let v = value("--web-token")?;
                if !crate::virtual_drive::web::token_is_valid(&v) {
                    return Err(format!(
                        "--web-token: expected at least {} characters of A-Z a-z 0-9 - _ . ~",
                        crate::virtual_drive::web::MIN_TOKEN_LEN
                    ));
                }
                web_token = Some(v);
            }
            Arg::Flag(f) if f == "--quick" => quick = true,
            Arg::Flag(f) if f == "--yes" => yes = true,
            Arg::Value(v) if file.is_none() => file = Some(v),
            Arg::Value(v) => return Err(format!("unexpected argument {}", v.display())),
            Arg::Flag(f) => return Err(format!("unknown flag {f} (see --help)")),
        }
    }
    let bauds: Vec<u32> = match baud.as_deref() {
        None => vec![115_200],
        Some("auto") if tool == "scan" => bauds().into_iter().rev().collect(),
        Some(b) => vec![b
            .parse()
            .ok()
            .filter(|b| bauds().contains(b))
            .ok_or(format!("--baud {b}: one of {:?}", bauds()))?],
    };
    let formats: Vec<u16> = match format.as_deref() {
        None if tool == "scan" => vec![0, 1, 2, 3],
        None => vec![0],
        Some(f) => vec![FORMATS
            .iter()
            .position(|x| *x == f)
            .ok_or(format!("--format {f}: one of {FORMATS:?}"))? as u16],
    };
    let line = LineSpec {
        baud: bauds[0],
        format: formats[0],
    };
    if tool == "scan" {
        let path = serial.ok_or("scan needs --serial PORT")?;
        let lines = if quick {
            vec![LineSpec::DEFAULT]
        } else {
            bauds
                .iter()
                .flat_map(|&baud| formats.iter().map(move |&format| LineSpec { baud, format }))
                .collect()
        };
        return Ok(Some(Tool::Scan(Scan {
            path,
            lines,
            timeout,
        })));
    }
    let endpoint = match (serial, tcp) {
        (Some(path), None) => Endpoint::Serial { path, line },
        (None, Some(peer)) => Endpoint::Tcp(peer),
        _ => {
            return Err(format!(
                "{tool}: give one of --serial PORT or --modbus-tcp-master HOST:PORT"
            ))
        }
    };
    let common = Common {
        endpoint,
        address,
        timeout,
    };
    match tool {
        "commission" => Ok(Some(Tool::Commission(Commission {
            common,
            web: web.ok_or("commission needs --web ADDR:PORT")?,
            web_token,
        }))),
        "save" | "restore" => {
            let params = Params {
                common,
                file: file.ok_or(format!("params {tool} needs a FILE"))?,
                yes,
            };
            Ok(Some(if tool == "save" {
                Tool::Save(params)
            } else {
                Tool::Restore(params)
            }))
        }
        t => Err(format!("unknown tool {t}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(s: &str) -> Vec<String> {
        s.split_whitespace().map(String::from).collect()
    }

    #[test]
    fn a_scan_at_auto_tries_every_baud_and_format() {
        let Some(Tool::Scan(s)) = parse(&args("scan --serial /dev/x --baud auto")).unwrap() else {
            panic!()
        };
        assert_eq!(s.lines.len(), 20);
        assert_eq!(s.lines[0], LineSpec::DEFAULT);
        let Some(Tool::Scan(s)) = parse(&args("scan --serial /dev/x --quick")).unwrap() else {
            panic!()
        };
        assert_eq!(s.lines, [LineSpec::DEFAULT]);
        let Some(Tool::Scan(s)) =
            parse(&args("scan --serial /dev/x --baud 19200 --format 8e1")).unwrap()
        else {
            panic!()
        };
        assert_eq!(s.lines, [LineSpec::from_pa(1, 1).unwrap()]);
    }

    #[test]
    fn bad_flags_are_named() {
        for (a, want) in [
            ("commission --serial /dev/x", "--web"),
            ("params save --serial /dev/x", "FILE"),
            ("params restore f.toml", "--serial"),
            (
                "commission --serial x --web 127.0.0.1:2 --baud 1234",
                "--baud 1234",
            ),
            ("scan --serial x --format 7N1", "--format 7N1"),
            ("params save --serial x --address 0 f", "--address 0"),
            ("params load", "save or restore"),
        ] {
            let e = parse(&args(a)).err().unwrap_or_default();
            assert!(e.contains(want), "{a}: {e}");
        }
    }
}
