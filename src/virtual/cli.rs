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

COMMISSIONING PAGE:
    --web ADDR:PORT          Serve a page on ADDR:PORT (only there; e.g.
                             127.0.0.1:8080): live scope, status, dictionary
                             and PA table, jog / move / homing, switches.
                             Its requests go through the drive's dispatcher
                             as a second port. Port 0 picks a free port.

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
        const SWITCHES: [&str; 6] = [
            "--help",
            "--version",
            "--no-pty",
            "--no-status",
            "--allow-limit-overlap",
            "--standard-exceptions",
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
            "--pty-link" => o.pty_link = Some(PathBuf::from(value("--pty-link")?)),
            "--tcp" => o.tcp.push(parse_socket("--tcp", &value("--tcp")?)?),
            "--modbus-tcp" => o
                .modbus_tcp
                .push(parse_socket("--modbus-tcp", &value("--modbus-tcp")?)?),
            "--web" => o.web = Some(parse_socket("--web", &value("--web")?)?),
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
mod tests {
    use super::*;

    fn run(args: &[&str]) -> Result<Options, UsageError> {
        match parse(args.iter().map(|s| s.to_string()))? {
            Command::Run(o) => Ok(*o),
            c => panic!("{c:?}"),
        }
    }

    /// Every example in --help is a command line the parser accepts.
    #[test]
    fn the_help_examples_parse() {
        let examples: Vec<&str> = HELP
            .split("EXAMPLES:")
            .nth(1)
            .unwrap()
            .lines()
            .map(str::trim)
            .filter(|l| l.starts_with("modbus-drive"))
            .collect();
        assert_eq!(examples.len(), 5);
        for line in examples {
            let args = line.split_whitespace().skip(1).map(String::from);
            assert!(
                matches!(parse(args), Ok(Command::Run(_))),
                "example `{line}` does not parse"
            );
        }
    }

    #[test]
    fn defaults_are_one_drive_on_a_pty() {
        let o = run(&[]).unwrap();
        assert_eq!(o, Options::default());
        assert!(o.pty);
        assert_eq!(o.drives, vec![1]);
    }

    #[test]
    fn every_flag_is_understood_in_both_spellings() {
        let o = run(&[
            "--pty-link=/tmp/x",
            "--tcp",
            "127.0.0.1:5020",
            "--tcp=[::1]:0",
            "--modbus-tcp",
            "127.0.0.1:5502",
            "--standard-exceptions",
            "--drives",
            "3,1,247",
            "--cw-limit",
            "-50000",
            "--ccw-limit=50000",
            "--home-switch",
            "-100:100",
            "--state",
            "s.bin",
            "--trace",
            "t.csv",
            "--plot",
            "p.svg",
            "--no-status",
            "--web",
            "127.0.0.1:8080",
            "--board=F103",
        ])
        .unwrap();
        assert_eq!(o.web, Some("127.0.0.1:8080".parse().unwrap()));
        assert_eq!(o.board, Board::F103);
        assert_eq!(o.pty_link, Some(PathBuf::from("/tmp/x")));
        assert_eq!(o.tcp.len(), 2);
        assert_eq!(o.modbus_tcp, vec!["127.0.0.1:5502".parse().unwrap()]);
        assert!(o.standard_exceptions);
        assert_eq!(o.drives, vec![3, 1, 247]);
        assert_eq!(o.axis.cw_limit_steps, Some(-50000));
        assert_eq!(o.axis.ccw_limit_steps, Some(50000));
        assert_eq!(
            o.axis.home_switch,
            Some(HomeSwitch {
                from_steps: -100,
                to_steps: 100
            })
        );
        assert!(o.state.is_some() && o.trace.is_some() && o.plot.is_some());
        assert!(!o.status_line);
    }

    #[test]
    fn repeatable_flags_and_port_0_may_repeat() {
        let o = run(&[
            "--tcp",
            "127.0.0.1:0",
            "--tcp",
            "127.0.0.1:0",
            "--modbus-tcp",
            "127.0.0.1:0",
            "--modbus-tcp",
            "127.0.0.1:5502",
            "--cw-limit",
            "-500",
        ])
        .unwrap();
        assert_eq!((o.tcp.len(), o.modbus_tcp.len()), (2, 2));
        assert_eq!(o.axis.cw_limit_steps, Some(-500));
    }

    #[test]
    fn overlapping_limits_need_the_flag_that_stages_a_wiring_fault() {
        let overlap = ["--cw-limit", "1000", "--ccw-limit", "500"];
        let Err(UsageError(msg)) = parse(overlap.iter().map(|s| s.to_string())) else {
            panic!("overlapping limits accepted without --allow-limit-overlap");
        };
        assert!(msg.contains("--allow-limit-overlap"), "{msg}");
        let o = run(&[&overlap[..], &["--allow-limit-overlap"]].concat()).unwrap();
        assert_eq!(o.axis.cw_limit_steps, Some(1000));
        assert_eq!(o.axis.ccw_limit_steps, Some(500));
    }

    #[test]
    fn bad_flags_are_refused_with_the_flag_named() {
        for (args, needle) in [
            (&["--bogus"][..], "--bogus"),
            (&["--tcp"], "--tcp needs a value"),
            (&["--tcp", "localhost"], "ADDR:PORT"),
            (
                &["--modbus-tcp", "localhost:502"],
                "--modbus-tcp localhost:502",
            ),
            (&["--modbus-tcp"], "--modbus-tcp needs a value"),
            (&["--no-pty=yes"], "--no-pty takes no value"),
            (&["--standard-exceptions=1"], "takes no value"),
            (&["--web", "8080"], "--web 8080: expected ADDR:PORT"),
            (&["--drives", "0"], "1..=247"),
            (&["--drives", "248"], "1..=247"),
            (&["--drives", "1,x"], "`x`"),
            (&["--drives", "2,2"], "twice"),
            (&["--cw-limit", "ten"], "--cw-limit"),
            (&["--cw-limit", "5", "--ccw-limit", "5"], "below"),
            (&["--home-switch", "5"], "FROM:TO"),
            (&["--board", "g474"], "g431 or f103"),
            (&["--board"], "--board needs a value"),
            (&["--home-switch", "5:4"], "FROM must not exceed"),
            (&["--no-pty"], "no transport"),
            (&["--pty-link", "--no-status"], "got the flag `--no-status`"),
            (&["--state", "--trace", "t.csv"], "--state needs a value"),
            (&["--state", ""], "got an empty one"),
            (&["--plot="], "--plot needs a value"),
            (&["--drives", "1", "--drives", "2"], "--drives given twice"),
            (&["--state", "a", "--state=b"], "--state given twice"),
            (&["--no-status", "--no-status"], "given twice"),
            (&["--trace", "x", "--plot", "x"], "same file x"),
            (&["--state", "s", "--pty-link", "s"], "same file s"),
            (
                &["--tcp", "127.0.0.1:5020", "--modbus-tcp", "127.0.0.1:5020"],
                "--tcp 127.0.0.1:5020 and --modbus-tcp 127.0.0.1:5020",
            ),
            (
                &["--modbus-tcp", "[::1]:502", "--modbus-tcp", "[::1]:502"],
                "one address",
            ),
            (&["--web", "127.0.0.1:80", "--tcp", "127.0.0.1:80"], "--web"),
            (&["/dev/ttyUSB0"], "unknown argument `/dev/ttyUSB0`"),
            (
                &["--no-pty", "--pty-link", "x", "--tcp", "127.0.0.1:1"],
                "contradict",
            ),
        ] {
            let e = run(args).unwrap_err();
            assert!(e.0.contains(needle), "{args:?}: {e}");
        }
    }

    #[test]
    fn help_names_every_flag() {
        for flag in [
            "--pty-link",
            "--no-pty",
            "--tcp",
            "--modbus-tcp",
            "--standard-exceptions",
            "--allow-limit-overlap",
            "--drives",
            "--board",
            "--cw-limit",
            "--ccw-limit",
            "--home-switch",
            "--state",
            "--trace",
            "--plot",
            "--no-status",
            "--web",
            "--help",
            "--version",
        ] {
            assert!(HELP.contains(flag), "{flag}");
        }
        assert_eq!(parse(["--help".to_string()]).unwrap(), Command::Help);
    }
}
