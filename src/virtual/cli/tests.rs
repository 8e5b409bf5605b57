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
        "--web-token",
        "0123456789abcdef-_.~",
        "--board=F103",
        "--stall-at",
        "-20000",
        "--slip=500@30000",
        "--encoder-noise",
        "3",
    ])
    .unwrap();
    let enc = o.axis.encoder;
    assert!(enc.on, "the fault flags imply --encoder");
    assert_eq!(enc.stall_at, Some(-20000));
    assert_eq!(enc.slip, Some((500, 30000)));
    assert_eq!(enc.noise_counts, 3);
    assert!(run(&["--encoder"]).unwrap().axis.encoder.on);
    assert!(run(&["--slip", "500"]).is_err());
    assert!(run(&["--slip", "a@1"]).is_err());
    assert!(run(&["--encoder-noise", "-1"]).is_err());
    assert_eq!(o.web, Some("127.0.0.1:8080".parse().unwrap()));
    assert_eq!(o.web_token.as_deref(), Some("0123456789abcdef-_.~"));
    assert_eq!(o.tcp_idle_timeout_s, Some(60), "the default");
    let idle = |v: &str| run(&["--tcp-idle-timeout", v]).unwrap().tcp_idle_timeout_s;
    assert_eq!(idle("5"), Some(5));
    assert_eq!(idle("0"), None);
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
        (
            &["--web", "0.0.0.0:80", "--web-token", "short"],
            "at least 16 characters",
        ),
        (
            &["--web", "0.0.0.0:80", "--web-token", "0123456789abcdef&x=1"],
            "A-Z a-z 0-9",
        ),
        (&["--web-token", "0123456789abcdef"], "without --web"),
        (&["--tcp-idle-timeout", "-1"], "expected seconds"),
        (&["--tcp-idle-timeout", "86401"], "expected seconds"),
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
