//! Command line of the virtual drive, read with `lexopt`: the parser splits
//! the arguments (`--flag value`, `--flag=value`, `-h`), and the messages,
//! which name the flag at fault, stay the program's own.

use std::fmt;
use std::net::SocketAddr;
use std::path::PathBuf;

use modbus_drive::boards::Board;

pub const HELP: &str = "\
modbus-drive (virtual drive): the drive core running in real time on this
machine, with a simulated axis per drive, reachable by any Modbus-RTU master.

USAGE:
    modbus-drive [OPTIONS]
    modbus-drive commission|scan|params ...   (a Modbus master of a real
                             drive: `modbus-drive commission --help`)

TRANSPORTS (both may be used at once):
    (default)                A pseudo-terminal: its path is printed on stderr;
                             open it like a serial port (any baud, 8N1).
    --pty-link PATH          Also make a symlink PATH -> the pseudo-terminal
                             (replaces an existing symlink, refuses other files).
    --no-pty                 No pseudo-terminal (then --tcp or --modbus-tcp
                             is required).
    --tcp ADDR:PORT          Listen for Modbus-RTU frames over TCP (same bytes,
                             same CRC as on the serial line; not Modbus-TCP).
                             Each connection is its own line to the drives;
                             several at once. Repeatable. Port 0 picks a free
                             port (printed on stderr).
    --modbus-tcp ADDR:PORT   Listen for Modbus TCP (MBAP header, no CRC: what
                             HMI/SCADA tools and PLCs speak). The unit id
                             selects the drive with that address; 0 and 255
                             reach the drive when there is only one. Several
                             clients at once. Repeatable; port 0 as --tcp.
    --tcp-idle-timeout SECS  Close a Modbus TCP connection without a request
                             in flight after SECS idle (0: never) [default:
                             60]. With 32 connected, a new client closes the
                             one idle the longest.

COMMISSIONING PAGE:
    --web ADDR:PORT          Serve a page on ADDR:PORT (only there; e.g.
                             127.0.0.1:8080): live scope, status, dictionary
                             and PA table, jog / move / homing, switches.
                             Its requests go through the drive's dispatcher
                             as a second port. Port 0 picks a free port.
                             Requests must name ADDR or localhost as Host.
    --web-token TOKEN        Every request to the page needs TOKEN (the URL's
                             ?token=, which sets a cookie, or the header
                             X-Modbus-Drive-Token); at least 16 characters of
                             A-Z a-z 0-9 - _ . ~. Beyond loopback a token is
                             always required: without this option a random
                             one is made and printed in the page's URL.

DRIVES AND AXES:
    --board g431|f103        The board whose step timer the drives run on, so
                             that its limits apply (step tick 10 MHz on the
                             G431, 8 MHz on the F103) [default: g431].
    --drives LIST            Addresses of the drives on the bus, comma
                             separated, 1..=247, distinct [default: 1]. Each
                             drive has its own simulated axis.
    --cw-limit STEPS         CW limit switch (negative side): active while the
                             position is at or below STEPS. Every axis.
    --ccw-limit STEPS        CCW limit switch (positive side): active while the
                             position is at or above STEPS. Every axis.
    --home-switch FROM:TO    Home switch: active while FROM <= position <= TO.
                             Every axis.
    --encoder                A simulated encoder on every motor (SPEC §8.8;
                             docs/closed-loop.md): PA17 = 4000 counts/rev at
                             start-up unless set. Also on whenever PA17 > 0.
    --stall-at STEPS         The motor stalls where the steps reach STEPS (once;
                             the stall ends when step output stops).
                             Implies --encoder.
    --slip STEPS@POS         The motor loses STEPS steps once where the steps
                             pass POS. Implies --encoder.
    --encoder-noise COUNTS   +-COUNTS of noise on every encoder reading.
                             Implies --encoder.
    --allow-limit-overlap    Accept a --cw-limit at or above the --ccw-limit:
                             where the two overlap both limits are active
                             (a wiring fault, e.g. a cut cable to normally
                             closed switches), and the drive faults there
                             (error register bit 0, SPEC §8.7).
    --standard-exceptions    Answer with the standard Modbus exception codes
                             only (PA55 = 1 on every drive at start-up):
                             vendor codes 5, 7, 11 become 2, code 8 becomes 3.
                             For generic masters and SCADA, which read 5 as
                             'acknowledge' and 11 as 'gateway target failed
                             to respond' (the drive offline).

FILES:
    --state FILE             The drives' parameter flash lives in FILE (created
                             erased if missing), so saved parameters survive a
                             restart. Drive n of --drives owns region n.
    --trace FILE.csv         Record time, address, position, velocity,
                             statusword and mode of every drive.
    --plot FILE.svg          On exit, draw position and velocity over time.

OUTPUT:
    --no-status              No status line on stderr (logs remain).
    -h, --help               This text.
    -V, --version            Version.

EXAMPLES:
    modbus-drive
        One drive at address 1 on a pseudo-terminal; point a master at the
        path printed on stderr, e.g. the statusword 0x6041 (= 24641):
        mbpoll -m rtu -b 115200 -P none -a 1 -0 -1 -t 4:hex -r 24641 PATH
    modbus-drive --pty-link /tmp/drive --no-status
        The same, reachable as /tmp/drive, without the status line.
    modbus-drive --no-pty --modbus-tcp 127.0.0.1:5502 --web 127.0.0.1:8080
        Modbus TCP for a PLC or SCADA, and the commissioning page.
    modbus-drive --drives 1,2,3 --state drives.bin --trace run.csv
        Three drives on one bus; saved parameters survive a restart; every
        drive's motion recorded.
    modbus-drive --cw-limit -20000 --ccw-limit 20000 --home-switch -100:100
        Limit and home switches on every axis, for homing (mode 6).

stdout carries exactly one line, `ready`, once every transport accepts frames.
Ctrl-C or SIGTERM stop the drive cleanly (trace and plot are written).
Exit status: 0 after a clean stop, 1 on a runtime error (e.g. a port in use),
2 on a bad command line.
";

/// A simulated limit or home switch window, in steps (inclusive bounds).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HomeSwitch {
    pub from_steps: i32,
    pub to_steps: i32,
}

/// Switch placement shared by every simulated axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AxisLayout {
    pub cw_limit_steps: Option<i32>,
    pub ccw_limit_steps: Option<i32>,
    pub home_switch: Option<HomeSwitch>,
    pub encoder: EncoderFaults,
}

/// The simulated encoder and the motor faults it shows (`--encoder`,
/// `--stall-at`, `--slip`, `--encoder-noise`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EncoderFaults {
    pub on: bool,
    pub stall_at: Option<i32>,
    /// (steps lost, position)
    pub slip: Option<(i32, i32)>,
    pub noise_counts: u16,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Options {
    pub pty: bool,
    pub pty_link: Option<PathBuf>,
    pub tcp: Vec<SocketAddr>,
    pub modbus_tcp: Vec<SocketAddr>,
    pub standard_exceptions: bool,
    pub drives: Vec<u8>,
    pub axis: AxisLayout,
    pub state: Option<PathBuf>,
    pub trace: Option<PathBuf>,
    pub plot: Option<PathBuf>,
    pub status_line: bool,
    pub web: Option<SocketAddr>,
    pub web_token: Option<String>,
    /// `None`: idle Modbus TCP connections stay open.
    pub tcp_idle_timeout_s: Option<u64>,
    pub board: Board,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            pty: true,
            pty_link: None,
            tcp: Vec::new(),
            modbus_tcp: Vec::new(),
            standard_exceptions: false,
            drives: vec![1],
            axis: AxisLayout::default(),
            state: None,
            trace: None,
            plot: None,
            status_line: true,
            web: None,
            web_token: None,
            tcp_idle_timeout_s: Some(60),
            board: Board::G431,
        }
    }
}

/// What the command line asks for.
#[derive(Debug, PartialEq, Eq)]
pub enum Command {
    /// Boxed: the options are far larger than the other variants.
    Run(Box<Options>),
    Help,
    Version,
}

/// A bad command line, phrased for the user.
#[derive(Debug, PartialEq, Eq)]
pub struct UsageError(pub String);

impl fmt::Display for UsageError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

fn err<T>(msg: impl Into<String>) -> Result<T, UsageError> {
    Err(UsageError(msg.into()))
}

pub fn parse<I: IntoIterator<Item = String>>(args: I) -> Result<Command, UsageError> {
    let mut o = Options::default();
    let mut limit_overlap = false;
    let mut seen: Vec<String> = Vec::new();
    let mut parser = lexopt::Parser::from_args(args);
    loop {
        let arg = match parser.next() {
            Ok(Some(arg)) => arg,
            Ok(None) => break,
            Err(e) => return err(format!("{e} (see --help)")),
        };
        let flag = match arg {
            lexopt::Arg::Short('h') => "--help".to_string(),
            lexopt::Arg::Short('V') => "--version".to_string(),
            lexopt::Arg::Long(name) => format!("--{name}"),
            lexopt::Arg::Short(c) => return err(format!("unknown argument `-{c}` (see --help)")),
            lexopt::Arg::Value(v) => {
                return err(format!(
                    "unknown argument `{}` (see --help)",
                    v.to_string_lossy()
                ))
            }
        };
        // a flag given twice would silently lose its first value
        const REPEATABLE: [&str; 2] = ["--tcp", "--modbus-tcp"];
        if !REPEATABLE.contains(&flag.as_str()) {
            if seen.contains(&flag) {
                return err(format!("{flag} given twice"));
            }
            seen.push(flag.clone());
        }
        const SWITCHES: [&str; 7] = [
            "--help",
            "--version",
            "--no-pty",
            "--no-status",
            "--allow-limit-overlap",
            "--standard-exceptions",
            "--encoder",
        ];
        if SWITCHES.contains(&flag.as_str()) {
            if let Some(v) = parser.optional_value() {
                let v = v.to_string_lossy().into_owned();
                return err(format!("{flag} takes no value (got `{flag}={v}`)"));
            }
        }
        let mut value = |name: &str| -> Result<String, UsageError> {
            match parser.value() {
                // `--pty-link --no-status` forgot the path; negative
                // numbers (`--cw-limit -500`) have one dash
                Ok(v) if v.to_string_lossy().starts_with("--") => err(format!(
                    "{name} needs a value, got the flag `{}` (see --help)",
                    v.to_string_lossy()
                )),
                Ok(v) if v.to_string_lossy().trim().is_empty() => {
                    err(format!("{name} needs a value, got an empty one"))
                }
                Ok(v) => Ok(v.to_string_lossy().into_owned()),
                Err(_) => err(format!("{name} needs a value (see --help)")),
            }
        };
        match flag.as_str() {
            "--help" => return Ok(Command::Help),
            "--version" => return Ok(Command::Version),
            "--no-pty" => o.pty = false,
            "--no-status" => o.status_line = false,
            "--allow-limit-overlap" => limit_overlap = true,
            "--standard-exceptions" => o.standard_exceptions = true,
            "--encoder" => o.axis.encoder.on = true,
            "--stall-at" => {
                o.axis.encoder.stall_at = Some(parse_steps("--stall-at", &value("--stall-at")?)?);
                o.axis.encoder.on = true;
            }
            "--slip" => {
                o.axis.encoder.slip = Some(parse_slip(&value("--slip")?)?);
                o.axis.encoder.on = true;
            }
            "--encoder-noise" => {
                let v = value("--encoder-noise")?;
                o.axis.encoder.noise_counts = v
                    .trim()
                    .parse()
                    .or_else(|_| err(format!("--encoder-noise {v}: expected counts 0..=65535")))?;
                o.axis.encoder.on = true;
            }
            "--pty-link" => o.pty_link = Some(PathBuf::from(value("--pty-link")?)),
            "--tcp" => o.tcp.push(parse_socket("--tcp", &value("--tcp")?)?),
            "--modbus-tcp" => o
                .modbus_tcp
                .push(parse_socket("--modbus-tcp", &value("--modbus-tcp")?)?),
            "--web" => o.web = Some(parse_socket("--web", &value("--web")?)?),
            "--tcp-idle-timeout" => {
                let v = value("--tcp-idle-timeout")?;
                o.tcp_idle_timeout_s = match v.trim().parse::<u64>() {
                    Ok(0) => None,
                    Ok(s @ 1..=86_400) => Some(s),
                    _ => {
                        return err(format!(
                            "--tcp-idle-timeout {v}: expected seconds 0..=86400"
                        ))
                    }
                };
            }
            "--web-token" => o.web_token = Some(parse_token(&value("--web-token")?)?),
            "--drives" => o.drives = parse_drives(&value("--drives")?)?,
            "--board" => {
                let v = value("--board")?;
                o.board = match Board::from_short_name(&v) {
                    Some(b) => b,
                    None => return err(format!("--board {v}: expected g431 or f103")),
                };
            }
            "--cw-limit" => {
                o.axis.cw_limit_steps = Some(parse_steps("--cw-limit", &value("--cw-limit")?)?)
            }
            "--ccw-limit" => {
                o.axis.ccw_limit_steps = Some(parse_steps("--ccw-limit", &value("--ccw-limit")?)?)
            }
            "--home-switch" => o.axis.home_switch = Some(parse_window(&value("--home-switch")?)?),
            "--state" => o.state = Some(PathBuf::from(value("--state")?)),
            "--trace" => o.trace = Some(PathBuf::from(value("--trace")?)),
            "--plot" => o.plot = Some(PathBuf::from(value("--plot")?)),
            _ => return err(format!("unknown argument `{flag}` (see --help)")),
        }
    }
    if !o.pty && o.pty_link.is_some() {
        return err("--pty-link and --no-pty contradict each other");
    }
    if !o.pty && o.tcp.is_empty() && o.modbus_tcp.is_empty() {
        return err("--no-pty leaves no transport: add --tcp or --modbus-tcp ADDR:PORT");
    }
    if o.web_token.is_some() && o.web.is_none() {
        return err("--web-token without --web: there is no page to guard");
    }
    check_distinct_sockets(&o)?;
    check_distinct_files(&o)?;
    if let (Some(cw), Some(ccw)) = (o.axis.cw_limit_steps, o.axis.ccw_limit_steps) {
        if cw >= ccw && !limit_overlap {
            return err(format!(
                "--cw-limit {cw} must lie below --ccw-limit {ccw} (CW is the negative side, \
                 SPEC §8.6); --allow-limit-overlap stages both limits active between them"
            ));
        }
    }
    Ok(Command::Run(Box::new(o)))
}

/// Two listeners on one address: the second bind would fail at start with
/// "address in use" and no word of which flags collide. Port 0 picks a
/// free port each time, so it may repeat.
fn check_distinct_sockets(o: &Options) -> Result<(), UsageError> {
    let mut all: Vec<(&str, SocketAddr)> = Vec::new();
    all.extend(o.tcp.iter().map(|a| ("--tcp", *a)));
    all.extend(o.modbus_tcp.iter().map(|a| ("--modbus-tcp", *a)));
    all.extend(o.web.iter().map(|a| ("--web", *a)));
    for (i, (f1, a1)) in all.iter().enumerate() {
        if let Some((f2, _)) = all[i + 1..]
            .iter()
            .find(|(_, a2)| a1.port() != 0 && a2 == a1)
        {
            return err(format!(
                "{f1} {a1} and {f2} {a1}: one address cannot serve two listeners"
            ));
        }
    }
    Ok(())
}

/// One file for two purposes would be overwritten by one of them.
fn check_distinct_files(o: &Options) -> Result<(), UsageError> {
    let all: Vec<(&str, &PathBuf)> = [
        ("--pty-link", &o.pty_link),
        ("--state", &o.state),
        ("--trace", &o.trace),
        ("--plot", &o.plot),
    ]
    .into_iter()
    .filter_map(|(f, p)| p.as_ref().map(|p| (f, p)))
    .collect();
    for (i, (f1, p1)) in all.iter().enumerate() {
        if let Some((f2, _)) = all[i + 1..].iter().find(|(_, p2)| p2 == p1) {
            return err(format!("{f1} and {f2} name the same file {}", p1.display()));
        }
    }
    Ok(())
}

fn parse_socket(flag: &str, v: &str) -> Result<SocketAddr, UsageError> {
    v.parse::<SocketAddr>().or_else(|_| {
        err(format!(
            "{flag} {v}: expected ADDR:PORT with a numeric address, e.g. 127.0.0.1:5020 \
             or [::1]:5020"
        ))
    })
}

/// A token goes into a URL and a cookie as it is: URL-safe characters only.
fn parse_token(v: &str) -> Result<String, UsageError> {
    if !super::web::token_is_valid(v) {
        return err(format!(
            "--web-token: expected at least {} characters of A-Z a-z 0-9 - _ . ~",
            super::web::MIN_TOKEN_LEN
        ));
    }
    Ok(v.to_string())
}

fn parse_drives(v: &str) -> Result<Vec<u8>, UsageError> {
    let mut out = Vec::new();
    for part in v.split(',') {
        let a = match part.trim().parse::<u8>() {
            Ok(a @ 1..=247) => a,
            _ => {
                return err(format!(
                    "--drives {v}: `{part}` is not a unicast address 1..=247 (SPEC §2)"
                ))
            }
        };
        if out.contains(&a) {
            return err(format!("--drives {v}: address {a} appears twice"));
        }
        out.push(a);
    }
    Ok(out)
}

fn parse_steps(flag: &str, v: &str) -> Result<i32, UsageError> {
    v.trim()
        .parse::<i32>()
        .or_else(|_| err(format!("{flag} {v}: expected a position in steps (i32)")))
}

fn parse_slip(v: &str) -> Result<(i32, i32), UsageError> {
    let Some((steps, at)) = v.split_once('@') else {
        return err(format!("--slip {v}: expected STEPS@POS, e.g. 500@20000"));
    };
    Ok((parse_steps("--slip", steps)?, parse_steps("--slip", at)?))
}

fn parse_window(v: &str) -> Result<HomeSwitch, UsageError> {
    let Some((a, b)) = v.split_once(':') else {
        return err(format!("--home-switch {v}: expected FROM:TO in steps"));
    };
    let from_steps = parse_steps("--home-switch", a)?;
    let to_steps = parse_steps("--home-switch", b)?;
    if from_steps > to_steps {
        return err(format!("--home-switch {v}: FROM must not exceed TO"));
    }
    Ok(HomeSwitch {
        from_steps,
        to_steps,
    })
}

#[cfg(test)]
mod tests;
