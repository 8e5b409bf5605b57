//! The HTTP side: `tiny_http` (synchronous, no async runtime, a few small
//! dependencies) on threads of its own. Routes:
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

use std::io::{self, Write};
use std::sync::mpsc::{self, Sender};
use std::sync::Arc;
use std::thread;
use std::time::Duration;

use tiny_http::{Header, Method, Request, Response, Server};

use super::commands::{Command, Profile};
use super::force::Switch;
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

pub fn spawn(server: Server, jobs: Sender<Job>, shared: Arc<Shared>) -> io::Result<()> {
    thread::Builder::new()
        .name("web".into())
        .spawn(move || {
            for request in server.incoming_requests() {
                let jobs = jobs.clone();
                let shared = Arc::clone(&shared);
                // One thread per request: an event stream lives as long as
                // its page, and a slow client holds up nobody else.
                let spawned = thread::Builder::new()
                    .name("web-request".into())
                    .spawn(move || route(request, &jobs, &shared));
                if spawned.is_err() {
                    // Out of threads: the request is dropped (tiny_http
                    // answers 500) and the next one tried.
                }
            }
        })
        .map(|_| ())
}

fn header(name: &str, value: &str) -> Header {
    Header::from_bytes(name.as_bytes(), value.as_bytes()).expect("static header is valid")
}

fn text(body: &str, content_type: &str, status: u16) -> Response<io::Cursor<Vec<u8>>> {
    Response::from_data(body.as_bytes().to_vec())
        .with_status_code(status)
        .with_header(header("Content-Type", content_type))
        .with_header(header("Cache-Control", "no-store"))
}

fn route(request: Request, jobs: &Sender<Job>, shared: &Shared) {
    let url = request.url().to_string();
    let (path, query) = url.split_once('?').unwrap_or((&url, ""));
    let response = match (request.method(), path) {
        (Method::Get, "/" | "/index.html") => text(INDEX, "text/html; charset=utf-8", 200),
        (Method::Get, "/page.js") => text(SCRIPT, "text/javascript; charset=utf-8", 200),
        (Method::Get, "/page.css") => text(STYLE, "text/css; charset=utf-8", 200),
        (Method::Get, "/api/state") => {
            let state = lock(shared).state.clone();
            text(&state, "application/json", 200)
        }
        (Method::Get, "/api/events") => {
            // Ends when the page goes away; nothing to report then.
            let _ = events(request, shared);
            return;
        }
        (Method::Post, "/api/cmd") => {
            let guarded = request
                .headers()
                .iter()
                .any(|h| h.field.equiv(GUARD.0) && h.value.as_str() == GUARD.1);
            if guarded {
                command(query, jobs)
            } else {
                text("missing X-Modbus-Drive header", "text/plain", 403)
            }
        }
        _ => text("not found", "text/plain", 404),
    };
    // A page that went away before its answer: nothing to do.
    let _ = request.respond(response);
}

/// Parses and queues a command, then waits for the loop's answer.
fn command(query: &str, jobs: &Sender<Job>) -> Response<io::Cursor<Vec<u8>>> {
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
    let get = |key: &str| {
        query
            .split('&')
            .filter_map(|kv| kv.split_once('='))
            .find(|(k, _)| *k == key)
            .map(|(_, v)| v)
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
fn events(request: Request, shared: &Shared) -> io::Result<()> {
    let mut w = request.into_writer();
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
        for bad in [
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
