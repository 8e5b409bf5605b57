//! `--web ADDR:PORT`: the commissioning page, served by the drive process.
//!
//! Two sides, joined by channels so that the drive loop never waits on a
//! browser:
//! - the HTTP side (`http.rs`, threads of its own) serves the page, hands
//!   every command to the loop as a [`Job`] and waits for its answer, and
//!   streams the scope samples the loop published (server-sent events);
//! - the loop side ([`WebPort::serve`], called by the drive loop between
//!   two wake-ups) runs the jobs — as Modbus requests through the drive's
//!   dispatcher (`modbus.rs`), never by writing drive state — and publishes
//!   samples and the page's view of each drive.
//!
//! The same page and HTTP side also run over a drive reached by Modbus
//! requests (`master/`, `modbus-drive commission`): [`WebPort::serve_remote`]
//! runs the jobs through a [`Remote`], and the master publishes what it
//! read as a [`Snapshot`] — the seam between the page and its back end.
//!
//! The page's requests never touch a bus line: they do not pass any line's
//! frame assembler, so they cannot break a frame a master is sending, and
//! they run between the loop's frame handling steps, so a master's frame
//! and a page request never interleave inside the dispatcher.

mod commands;
mod exceptions;
mod force;
mod guard;
mod http;
mod modbus;
mod server;
mod state;

use std::collections::VecDeque;
use std::fmt::Write;
use std::io;
use std::net::SocketAddr;
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Condvar, Mutex};

use modbus_drive::rtu::LineConfig;
use modbus_drive::slave::Slave;

pub use commands::Ctx;
pub use exceptions::ExceptionLog;
pub use force::{Forced, Switch};
pub use guard::{token_is_valid, MIN_TOKEN_LEN};
pub use modbus::{parse_reply, Answer, Dispatch, Pdu};
pub use state::{quote, OdValue, Snapshot, View, FOLLOWING_ERROR};

use commands::{requests, Command, Step};
use modbus::transact;

/// Scope sample period: 100 samples per second.
const SAMPLE_PERIOD_US: u64 = 10_000;
/// Samples kept for a page that connects: the scope's 10 s, and a margin.
const SAMPLES_KEPT: usize = 1_200;
/// How often the page's view of the drives is rebuilt.
const STATE_PERIOD_US: u64 = 100_000;

/// A drive as the page needs it.
pub trait Target: Dispatch {
    fn view<'a>(&'a self, port: &'a Slave) -> View<'a>;
    fn force(&mut self, switch: Switch, state: Option<bool>);
}

/// A drive the page reaches by Modbus requests over a line it does not
/// own (the commissioning master).
pub trait Remote {
    /// The drive's state and word order, read afresh when the line
    /// allows (a command is judged on the state it will meet).
    fn ctx(&mut self) -> Ctx;
    /// Sends one request: the frame as sent, the reply as received (whole
    /// frame), and the answer, or why there was none (timeout, line gone).
    fn exchange(&mut self, pdu: &Pdu) -> (Vec<u8>, Vec<u8>, Result<Answer, String>);
}

/// A command from the page for drive `drive`, and where its answer goes.
pub struct Job {
    drive: usize,
    command: Command,
    answer: Sender<String>,
}

/// What the loop publishes for the HTTP side.
#[derive(Default)]
struct Published {
    /// Number of the newest sample.
    seq: u64,
    /// `(seq, JSON array)`, oldest first.
    samples: VecDeque<(u64, String)>,
    /// JSON of every drive's view.
    state: String,
}

#[derive(Default)]
struct Shared {
    published: Mutex<Published>,
    changed: Condvar,
}

/// The loop's end of the page.
pub struct WebPort {
    pub addr: SocketAddr,
    /// The token a request needs (given, or made for a non-loopback
    /// address; `guard.rs`).
    token: Option<String>,
    jobs: Receiver<Job>,
    shared: Arc<Shared>,
    /// Per drive, the page's own slave state (its §6 counters).
    ports: Vec<Slave>,
    next_sample_us: u64,
    next_state_us: u64,
    /// The Modbus TCP server's counters (JSON), when it runs.
    modbus_tcp: Option<String>,
}

impl WebPort {
    /// Listens on `addr` (only there) and starts the HTTP side.
    pub fn start(addr: SocketAddr, token: Option<String>, drives: usize) -> io::Result<Self> {
        let listener = std::net::TcpListener::bind(addr)?;
        let addr = listener.local_addr()?;
        let guard = guard::Guard::new(addr, token)?;
        let token = guard.token().map(String::from);
        let (tx, jobs) = mpsc::channel();
        let shared = Arc::new(Shared::default());
        http::spawn(listener, guard, tx, Arc::clone(&shared))?;
        Ok(Self {
            addr,
            token,
            jobs,
            shared,
            ports: vec![Slave::new(); drives],
            next_sample_us: 0,
            next_state_us: 0,
            modbus_tcp: None,
        })
    }

    /// Runs the page's waiting commands and publishes what is due. Returns
    /// the drives that handled requests, each with the new line format its
    /// requests set (if any): the caller logs their events and puts the
    /// line format in force, as after a bus reply.
    pub fn serve<T: Target>(
        &mut self,
        now_us: u64,
        drives: &mut [T],
    ) -> Vec<(usize, Option<LineConfig>)> {
        let mut touched: Vec<(usize, Option<LineConfig>)> = Vec::new();
        while let Ok(job) = self.jobs.try_recv() {
            let mut line = None;
            let answer = self.execute(job.drive, &job.command, now_us, drives, &mut line);
            if job.drive < drives.len() {
                match touched.iter_mut().find(|(di, _)| *di == job.drive) {
                    Some((_, l)) => *l = line.or(*l),
                    None => touched.push((job.drive, line)),
                }
            }
            // The page may have given up waiting; nothing to do then.
            let _ = job.answer.send(answer);
        }
        if now_us >= self.next_sample_us {
            self.publish_sample(now_us, drives);
            self.next_sample_us = (self.next_sample_us + SAMPLE_PERIOD_US).max(now_us);
        }
        if now_us >= self.next_state_us || !touched.is_empty() {
            self.publish_state(drives);
            self.next_state_us = now_us + STATE_PERIOD_US;
        }
        touched
    }

    /// The page's address to open, with the token when one is required.
    pub fn url(&self) -> String {
        match &self.token {
            Some(t) => format!("http://{}/?token={t}", self.addr),
            None => format!("http://{}/", self.addr),
        }
    }

    /// The Modbus TCP server's counters, published with the next view.
    pub fn set_modbus_tcp(&mut self, json: String) {
        self.modbus_tcp = Some(json);
    }

    /// When [`WebPort::serve`] next has something to publish.
    pub fn next_due_us(&self) -> u64 {
        self.next_sample_us.min(self.next_state_us)
    }

    fn execute<T: Target>(
        &mut self,
        di: usize,
        command: &Command,
        now_us: u64,
        drives: &mut [T],
        line: &mut Option<LineConfig>,
    ) -> String {
        let (Some(drive), Some(port)) = (drives.get_mut(di), self.ports.get_mut(di)) else {
            return error_json(&format!("there is no drive number {di}"));
        };
        if let Command::Force { switch, state } = *command {
            drive.force(switch, state);
            return "{\"ok\":true,\"steps\":[]}".into();
        }
        let steps = match requests(command, Ctx::of(drive.device())) {
            Ok(s) => s,
            Err(why) => return error_json(&why),
        };
        run_steps(&steps, |pdu| {
            // the request as it went out: from the address it was sent to
            let frame = pdu.frame(drive.device().address());
            let (answer, changed) = transact(drive, port, pdu, now_us);
            *line = changed.or(*line);
            let reply = match &answer {
                Answer::Ok(p) => p.clone(),
                Answer::Malformed(r) => r.clone(),
                _ => Vec::new(),
            };
            (frame, reply, Ok(answer))
        })
    }

    /// The page over a drive reached by Modbus requests (the commissioning
    /// master, `--serial` / `--modbus-tcp-master`): runs the page's waiting
    /// commands through `remote`. Returns whether any ran.
    pub fn serve_remote<R: Remote>(&mut self, remote: &mut R) -> bool {
        let mut any = false;
        while let Ok(job) = self.jobs.try_recv() {
            any = true;
            let answer = if job.drive != 0 {
                error_json(&format!("there is no drive number {}", job.drive))
            } else if let Command::Force { .. } = job.command {
                error_json("a real drive's switches are wired, not forced from the page")
            } else {
                match requests(&job.command, remote.ctx()) {
                    Ok(steps) => run_steps(&steps, |pdu| remote.exchange(pdu)),
                    Err(why) => error_json(&why),
                }
            };
            let _ = job.answer.send(answer);
        }
        any
    }

    /// Publishes one scope sample of a remote drive taken at `t_us`.
    pub fn publish_remote_sample(&mut self, t_us: u64, sample: [Option<i64>; 4]) {
        let f = |v: Option<i64>| v.map_or("null".into(), |v| v.to_string());
        self.push_sample(format!(
            "[{:.3},[{},{},{},{}]]",
            t_us as f64 / 1e6,
            f(sample[0]),
            f(sample[1]),
            f(sample[2]),
            f(sample[3])
        ));
    }

    /// Publishes the page's view of a remote drive.
    pub fn publish_remote_state(&mut self, snapshot: &Snapshot<'_>, sample_period_ms: u64) {
        let s = format!(
            "{{\"sample_period_ms\":{sample_period_ms},\"drives\":[{}]}}",
            state::snapshot_json(snapshot)
        );
        lock(&self.shared).state = s;
    }

    fn publish_sample<T: Target>(&mut self, now_us: u64, drives: &[T]) {
        let mut line = format!("[{:.3}", now_us as f64 / 1e6);
        for (di, d) in drives.iter().enumerate() {
            let v = d.view(&self.ports[di]);
            let dev = v.device;
            use modbus_drive::dictionary::DriveLayer;
            let _ = write!(
                line,
                ",[{},{},{},{}]",
                dev.drive().actual_position(),
                dev.drive().actual_velocity_rpm(),
                state::entry_value(dev, state::FOLLOWING_ERROR)
                    .map_or("null".into(), |v| v.to_string()),
                dev.drive().statusword()
            );
        }
        line.push(']');
        self.push_sample(line);
    }

    fn push_sample(&mut self, line: String) {
        let mut p = lock(&self.shared);
        p.seq += 1;
        let seq = p.seq;
        if p.samples.len() == SAMPLES_KEPT {
            p.samples.pop_front();
        }
        p.samples.push_back((seq, line));
        drop(p);
        self.shared.changed.notify_all();
    }

    fn publish_state<T: Target>(&mut self, drives: &[T]) {
        let mut s = format!(
            "{{\"sample_period_ms\":{},\"drives\":[",
            SAMPLE_PERIOD_US / 1000
        );
        for (di, d) in drives.iter().enumerate() {
            if di > 0 {
                s.push(',');
            }
            s.push_str(&state::drive_json(&d.view(&self.ports[di])));
        }
        s.push(']');
        if let Some(m) = &self.modbus_tcp {
            let _ = write!(s, ",\"modbus_tcp\":{m}");
        }
        s.push('}');
        lock(&self.shared).state = s;
    }
}

/// The lock, also after a panicking HTTP thread (the data stays whole:
/// every writer replaces values, none leaves them half-made).
fn lock(shared: &Shared) -> std::sync::MutexGuard<'_, Published> {
    shared
        .published
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Sends `steps` in order through `send` until one is not answered
/// normally: a command is never sent past a refusal or a lost reply, and
/// the answer says at which step it stopped.
fn run_steps(
    steps: &[Step],
    mut send: impl FnMut(&Pdu) -> (Vec<u8>, Vec<u8>, Result<Answer, String>),
) -> String {
    let mut stopped = None;
    let mut out = String::from("[");
    for (i, step) in steps.iter().enumerate() {
        let (frame, reply, answer) = send(&step.pdu);
        let (kind, code) = match &answer {
            Ok(Answer::Ok(_)) => ("ok", 0),
            Ok(Answer::Exception(c)) => ("exception", *c),
            Ok(Answer::Silent) => ("silent", 0),
            Ok(Answer::Malformed(_)) => ("malformed", 0),
            Err(_) => ("no reply", 0),
        };
        let _ = write!(
            out,
            "{}{{\"label\":{},\"request\":{},\"answer\":\"{kind}\",\"code\":{code},\"reply\":{}}}",
            if i > 0 { "," } else { "" },
            state::quote(&step.label),
            state::quote(&hex(&frame)),
            state::quote(&hex(&reply)),
        );
        match answer {
            Ok(Answer::Ok(_)) => {}
            Ok(_) if steps.len() == 1 => {
                stopped = Some(String::new());
                break;
            }
            other => {
                let why = match other {
                    Err(why) => why,
                    Ok(Answer::Exception(c)) => format!("exception {c}"),
                    Ok(_) => format!("answer {kind}"),
                };
                stopped = Some(if steps.len() == 1 {
                    why
                } else {
                    format!(
                        "stopped at step {} of {} ({}): {why}; the later steps were not sent",
                        i + 1,
                        steps.len(),
                        step.label
                    )
                });
                break;
            }
        }
    }
    out.push(']');
    match stopped {
        None => format!("{{\"ok\":true,\"steps\":{out}}}"),
        Some(e) if e.is_empty() => format!("{{\"ok\":false,\"steps\":{out}}}"),
        Some(e) => format!(
            "{{\"ok\":false,\"error\":{},\"steps\":{out}}}",
            state::quote(&e)
        ),
    }
}

fn error_json(why: &str) -> String {
    format!(
        "{{\"ok\":false,\"error\":{},\"steps\":[]}}",
        state::quote(why)
    )
}

fn hex(bytes: &[u8]) -> String {
    let mut s = String::with_capacity(3 * bytes.len());
    for (i, b) in bytes.iter().enumerate() {
        if i > 0 {
            s.push(' ');
        }
        let _ = write!(s, "{b:02X}");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use modbus_drive::drive::PowerState;

    fn enable() -> Vec<Step> {
        let ctx = Ctx {
            state: PowerState::SwitchOnDisabled,
            low_first: false,
        };
        requests(&Command::Enable, ctx).unwrap()
    }

    #[test]
    fn a_sequence_stops_at_the_step_that_got_no_answer_and_says_which() {
        let mut sent = Vec::new();
        let json = run_steps(&enable(), |pdu| {
            sent.push(pdu.clone());
            let frame = pdu.frame(1);
            if sent.len() == 2 {
                (frame, Vec::new(), Err("no reply within 300 ms".into()))
            } else {
                (frame.clone(), frame, Ok(Answer::Ok(pdu.0.clone())))
            }
        });
        assert_eq!(sent.len(), 2, "nothing sent past the failing step");
        assert!(json.starts_with("{\"ok\":false,"), "{json}");
        assert!(
            json.contains(
                "stopped at step 2 of 3 (0x6040 = 0x0007): no reply within 300 ms; \
                 the later steps were not sent"
            ),
            "{json}"
        );
        assert_eq!(json.matches("\"label\"").count(), 2, "{json}");
        assert!(json.contains("\"answer\":\"no reply\""), "{json}");
    }

    #[test]
    fn a_refused_step_stops_the_sequence_with_its_exception() {
        let json = run_steps(&enable(), |pdu| {
            (pdu.frame(1), Vec::new(), Ok(Answer::Exception(6)))
        });
        assert!(json.contains("stopped at step 1 of 3"), "{json}");
        assert!(json.contains("\"code\":6"), "{json}");
        let all = run_steps(&enable(), |pdu| {
            (pdu.frame(1), pdu.frame(1), Ok(Answer::Ok(pdu.0.clone())))
        });
        assert!(all.starts_with("{\"ok\":true,"), "{all}");
        assert_eq!(all.matches("\"label\"").count(), 3, "{all}");
    }
}
