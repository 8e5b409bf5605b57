//! The page's routes, on the bounded server of `server.rs`, behind the
//! `Host` and token checks of `guard.rs`:
//! - `GET /`, `/page.js`, `/page.css`: the page, embedded in the binary;
//! - `GET /api/state`: every drive's view (JSON), as last published;
//! - `GET /api/events`: scope samples as server-sent events, the kept ones
//!   first;
//! - `POST /api/cmd?d=DRIVE&c=COMMAND&…`: a command, answered with the
//!   requests it sent and what the drive replied.
//!
//! A POST must carry the header `X-Modbus-Drive: page`. The page's own
//! script sets it; a form or script of another site cannot (a browser asks
//! this server's permission first, and it never gives it), so another web
//! page open in the same browser cannot move the axis.
//!
//! An event stream lives as long as its page, so it runs on a thread of
//! its own rather than hold a worker, and at most [`MAX_STREAMS`] run at
//! once (the next is answered 503).

use std::io::{self, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{self, Sender};
use std::sync::Arc;
use std::thread;
use std::time::Duration;

use super::commands::{Command, Profile};
use super::force::Switch;
use super::guard::{Guard, Refusal, TOKEN_HEADER};
use super::server::{self, Method, Request, Response};
use super::{lock, Job, Shared};

const INDEX: &str = include_str!("page/index.html");
const SCRIPT: &str = include_str!("page/page.js");
const STYLE: &str = include_str!("page/page.css");

/// The header every POST must carry.
const GUARD: (&str, &str) = ("X-Modbus-Drive", "page");
/// Longest wait for the drive loop to run a command.
const JOB_TIMEOUT: Duration = Duration::from_secs(5);
/// An idle event stream sends a comment this often, so that a closed page
/// is noticed and its thread ends.
const KEEPALIVE: Duration = Duration::from_secs(2);
/// Event streams at once: a few pages open on one drive, with a margin.
pub const MAX_STREAMS: usize = 8;
/// Longest URL taken (the longest command is a raw PDU of 253 bytes).
const MAX_URL: usize = 2048;

struct Site {
    guard: Guard,
    jobs: Sender<Job>,
    shared: Arc<Shared>,
    streams: Arc<AtomicUsize>,
}

pub fn spawn(
    listener: TcpListener,
    guard: Guard,
    jobs: Sender<Job>,
    shared: Arc<Shared>,
) -> io::Result<()> {
    let site = Site {
        guard,
        jobs,
        shared,
        streams: Arc::new(AtomicUsize::new(0)),
    };
    server::spawn(listener, server::LIMITS, move |request| {
        route(request, &site)
    })
}

fn text(body: &str, content_type: &str, status: u16) -> Response {
    Response::new(status, content_type, body.as_bytes().to_vec())
        .with_header("Cache-Control", "no-store")
}

fn route(request: Request, site: &Site) {
    let url = request.url().to_string();
    if url.len() > MAX_URL {
        let _ = request.respond(text("URL too long", "text/plain", 414));
        return;
    }
    let (path, query) = url.split_once('?').unwrap_or((&url, ""));
    let query_token = query_value(query, "token").and_then(Result::ok);
    let checked = site.guard.check(
        request.header("Host"),
        query_token.as_deref(),
        request.header(TOKEN_HEADER),
        request.header("Cookie"),
    );
    match checked {
        Ok(()) => {}
        Err(Refusal::Host) => {
            let why = "Host is not this drive's address (DNS rebinding?)";
            let _ = request.respond(text(why, "text/plain", 403));
            return;
        }
        Err(Refusal::Token) => {
            let why = "a token is required: open the URL the drive printed (…/?token=…)";
            let _ = request.respond(text(why, "text/plain", 401));
            return;
        }
    }
    let response = match (request.method(), path) {
        (Method::Get, "/" | "/index.html") => {
            let page = text(INDEX, "text/html; charset=utf-8", 200);
            // the page's URL carried the token: its later requests carry
            // the cookie instead
            match (&query_token, site.guard.token()) {
                (Some(t), Some(_)) => page.with_header(
                    "Set-Cookie",
                    &format!(
                        "{}={t}; Path=/; HttpOnly; SameSite=Strict",
                        site.guard.cookie_name()
                    ),
                ),
                _ => page,
            }
        }
        (Method::Get, "/page.js") => text(SCRIPT, "text/javascript; charset=utf-8", 200),
        (Method::Get, "/page.css") => text(STYLE, "text/css; charset=utf-8", 200),
        (Method::Get, "/api/state") => {
            let state = lock(&site.shared).state.clone();
            text(&state, "application/json", 200)
        }
        (Method::Get, "/api/events") => {
            start_events(request, site);
            return;
        }
        (Method::Post, "/api/cmd") => {
            let guarded = request.header(GUARD.0) == Some(GUARD.1);
            if guarded {
                command(query, &site.jobs)
            } else {
                text("missing X-Modbus-Drive header", "text/plain", 403)
            }
        }
        _ => text("not found", "text/plain", 404),
    };
    // A page that went away before its answer: nothing to do.
    let _ = request.respond(response);
}

/// Hands the event stream to a thread of its own, or answers 503 when
/// [`MAX_STREAMS`] run already.
fn start_events(request: Request, site: &Site) {
    let streams = Arc::clone(&site.streams);
    if streams.fetch_add(1, Ordering::SeqCst) >= MAX_STREAMS {
        streams.fetch_sub(1, Ordering::SeqCst);
        let why = "too many event streams open";
        let _ = request.respond(text(why, "text/plain", 503));
        return;
    }
    let shared = Arc::clone(&site.shared);
    let stream = request.into_stream();
    let spawned = thread::Builder::new()
        .name("web-events".into())
        .spawn(move || {
            // Ends when the page goes away; nothing to report then.
            let _ = events(stream, &shared);
            streams.fetch_sub(1, Ordering::SeqCst);
        });
    if spawned.is_err() {
        // out of threads: the stream is dropped with its closure
        site.streams.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Parses and queues a command, then waits for the loop's answer.
fn command(query: &str, jobs: &Sender<Job>) -> Response {
    let (drive, command) = match parse_command(query) {
        Ok(c) => c,
        Err(why) => return text(&super::error_json(&why), "application/json", 400),
    };
    let (tx, rx) = mpsc::channel();
    let job = Job {
        drive,
        command,
        answer: tx,
    };
    if jobs.send(job).is_err() {
        return text(
            &super::error_json("the drive stopped"),
            "application/json",
            503,
        );
    }
    match rx.recv_timeout(JOB_TIMEOUT) {
        Ok(answer) => text(&answer, "application/json", 200),
        Err(_) => text(
            &super::error_json("the drive did not answer in time"),
            "application/json",
            503,
        ),
    }
}

/// `d=DRIVE&c=COMMAND&…` → drive number and command.
pub fn parse_command(query: &str) -> Result<(usize, Command), String> {
    let pairs = query
        .split('&')
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| Ok((k, percent_decode(v)?)))
        .collect::<Result<Vec<_>, String>>()?;
    let get = |key: &str| {
        pairs
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, v)| v.as_str())
    };
    let number = |key: &str| -> Result<i64, String> {
        let v = get(key).ok_or_else(|| format!("`{key}` is missing"))?;
        let parsed = match v.strip_prefix("0x").or_else(|| v.strip_prefix("0X")) {
            Some(h) => i64::from_str_radix(h, 16),
            None => v.parse::<i64>(),
        };
        parsed.map_err(|_| format!("`{key}={v}` is not a number"))
    };
    let ranged = |key: &str, lo: i64, hi: i64| -> Result<i64, String> {
        let v = number(key)?;
        if (lo..=hi).contains(&v) {
            Ok(v)
        } else {
            Err(format!("`{key}={v}` is outside {lo}..={hi}"))
        }
    };
    let profile = || -> Result<Profile, String> {
        Ok(Profile {
            speed: ranged("speed", 0, i64::from(i32::MAX))? as u32,
            accel: ranged("accel", 0, 0xFFFF)? as u16,
        })
    };
    let drive = ranged("d", 0, 246)? as usize;
    let c = get("c").ok_or("`c` is missing")?;
    let command = match c {
        "write" => Command::Write {
            index: ranged("index", 0, 0xFFFF)? as u16,
            value: number("value")?,
        },
        "enable" => Command::Enable,
        "disable" => Command::Disable,
        "reset" => Command::FaultReset,
        "quickstop" => Command::QuickStop,
        "halt" => Command::Halt,
        "jog" => Command::Jog {
            forward: match get("dir") {
                Some("pos") => true,
                Some("neg") => false,
                _ => return Err("`dir` must be pos or neg".into()),
            },
            profile: profile()?,
        },
        "jogstop" => Command::JogStop,
        "defaults" => Command::Defaults,
        "move" => Command::Move {
            target: ranged("target", i64::from(i32::MIN), i64::from(i32::MAX))? as i32,
            relative: get("relative") == Some("1"),
            profile: profile()?,
        },
        "home" => Command::Home,
        "save" => Command::Save,
        "raw" => Command::Raw(parse_hex(get("pdu").unwrap_or(""))?),
        "force" => Command::Force {
            switch: get("switch")
                .and_then(Switch::parse)
                .ok_or("`switch` must be cw, ccw or home")?,
            state: match get("state") {
                Some("on") => Some(true),
                Some("off") => Some(false),
                Some("auto") => None,
                _ => return Err("`state` must be on, off or auto".into()),
            },
        },
        other => return Err(format!("unknown command `{other}`")),
    };
    Ok((drive, command))
}

/// The value of `key` in a query, percent-decoded.
fn query_value(query: &str, key: &str) -> Option<Result<String, String>> {
    query
        .split('&')
        .filter_map(|kv| kv.split_once('='))
        .find(|(k, _)| *k == key)
        .map(|(_, v)| percent_decode(v))
}

/// A query value as a form sends it: `%XX` is a byte, `+` a space.
fn percent_decode(v: &str) -> Result<String, String> {
    let bad = || format!("`{v}` is not a well-formed query value");
    let b = v.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'%' => {
                let hex = b.get(i + 1..i + 3).ok_or_else(bad)?;
                let hex = std::str::from_utf8(hex).map_err(|_| bad())?;
                out.push(u8::from_str_radix(hex, 16).map_err(|_| bad())?);
                i += 3;
            }
            b'+' => {
                out.push(b' ');
                i += 1;
            }
            c => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8(out).map_err(|_| bad())
}

/// `0360410001` → bytes.
fn parse_hex(v: &str) -> Result<Vec<u8>, String> {
    let bad = || format!("`pdu={v}` is not hex bytes");
    if !v.len().is_multiple_of(2) || !v.is_ascii() {
        return Err(bad());
    }
    (0..v.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&v[i..i + 2], 16).map_err(|_| bad()))
        .collect()
}

/// The scope stream: the kept samples, then each new one as it comes.
fn events(mut w: TcpStream, shared: &Shared) -> io::Result<()> {
    w.write_all(
        b"HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\n\
          Connection: close\r\n\r\n",
    )?;
    w.flush()?;
    let mut last = 0u64;
    loop {
        let batch = {
            let mut p = lock(shared);
            if p.seq == last {
                p = shared
                    .changed
                    .wait_timeout(p, KEEPALIVE)
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .0;
            }
            let lines: Vec<&str> = p
                .samples
                .iter()
                .filter(|(seq, _)| *seq > last)
                .map(|(_, l)| l.as_str())
                .collect();
            let batch = lines.join(",");
            last = p.seq;
            batch
        };
        if batch.is_empty() {
            w.write_all(b": idle\n\n")?;
        } else {
            write!(w, "data: [{batch}]\n\n")?;
        }
        w.flush()?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_parse_from_the_query() {
        let (d, c) = parse_command("d=0&c=write&index=0x6060&value=-3").unwrap();
        assert_eq!(
            (d, c),
            (
                0,
                Command::Write {
                    index: 0x6060,
                    value: -3
                }
            )
        );
        let (_, c) =
            parse_command("c=move&d=1&target=-5000&speed=100&accel=50&relative=1").unwrap();
        assert_eq!(
            c,
            Command::Move {
                target: -5000,
                relative: true,
                profile: Profile {
                    speed: 100,
                    accel: 50
                }
            }
        );
        let (_, c) = parse_command("d=0&c=force&switch=home&state=auto").unwrap();
        assert_eq!(
            c,
            Command::Force {
                switch: Switch::Home,
                state: None
            }
        );
        let (_, c) = parse_command("d=0&c=raw&pdu=0360410001").unwrap();
        assert_eq!(c, Command::Raw(vec![0x03, 0x60, 0x41, 0x00, 0x01]));
        // what a browser's URLSearchParams makes of a typed `+5` and ` 0x10`
        let (_, c) = parse_command("d=0&c=write&index=%30x6060&value=%2B5").unwrap();
        assert_eq!(
            c,
            Command::Write {
                index: 0x6060,
                value: 5
            }
        );
        let (_, c) = parse_command("d=0&c=move&target=-7&speed=1&accel=2&relative=%31").unwrap();
        assert!(matches!(c, Command::Move { relative: true, .. }));
        assert_eq!(percent_decode("a+b%20c%2b"), Ok("a b c+".into()));
        for bad in ["%", "%2", "%zz", "%FF"] {
            assert!(percent_decode(bad).is_err(), "{bad}");
        }
        for bad in [
            "d=0&c=write&index=1&value=%2",
            "d=0&c=write&index=1&value=+5",
            "d=0&c=raw&pdu=036",
            "d=0&c=raw&pdu=zz",
            "c=enable",
            "d=0",
            "d=0&c=fly",
            "d=0&c=write&index=70000&value=1",
            "d=0&c=write&index=1&value=x",
            "d=0&c=jog&dir=up&speed=1&accel=1",
            "d=0&c=move&target=3000000000&speed=1&accel=1",
            "d=0&c=force&switch=cw&state=maybe",
        ] {
            assert!(parse_command(bad).is_err(), "{bad}");
        }
    }
}
