//! `commission`: the commissioning page over a Modbus master. The page and
//! its HTTP side are the virtual drive's (`web/`); here the drive behind
//! them is reached by requests on a line:
//! - every loop: the page's waiting commands, then one scope sample (the DP
//!   monitor 0x0000..0x0013 and the statusword), as fast as the line
//!   answers, so the rate the page shows is the rate the line allows;
//! - between two samples, one request of the tables' refresh (PA0..PA59 in
//!   one read, a §6 counter, a dictionary entry), round robin;
//! - a request that gets no answer marks the drive gone on the page, with
//!   the frame; it is tried again until it answers.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use modbus_drive::dictionary::Access;
use modbus_drive::motion::Switches;
use modbus_drive::slave::Counters;

use super::cli::Commission;
use super::status::power_state;
use super::{hex, Failure, Master};
use crate::virtual_drive::registers::{position, DataType, PA_COUNT, TABLE};
use crate::virtual_drive::web::{
    quote, Answer, Ctx, ExceptionLog, OdValue, Pdu, Remote, Snapshot, WebPort, FOLLOWING_ERROR,
};

/// The wait for an EE operation's reply.
const EE_TIMEOUT: Duration = Duration::from_secs(3);
/// The EE command register (SPEC §9).
const EE_REGISTER: u16 = 0x003A;
/// The page's view is rebuilt this often.
const STATE_PERIOD: Duration = Duration::from_millis(200);
/// Wait between two tries of a drive that is gone.
const RETRY: Duration = Duration::from_millis(250);
/// DP monitor words read per sample: DP-SPd .. DP-Err (SPEC §9).
const MONITOR_WORDS: u16 = 0x14;
const STATUSWORD: u16 = 0x6041;
const WORD_ORDER: u16 = 0x6000;
/// Diagnostics sub-functions of the §6 counters, in [`Counters`] order.
const COUNTER_SUBS: [u16; 7] = [0x0B, 0x0C, 0x0D, 0x0E, 0x0F, 0x11, 0x12];

/// One request of the tables' refresh.
#[derive(Clone, Copy)]
enum Refresh {
    Pas,
    Counter(usize),
    Entry(usize),
}

/// The drive as the master last read it.
struct RemoteDrive {
    master: Master,
    log: ExceptionLog,
    statusword: u16,
    monitor: Vec<u16>,
    low_first: bool,
    pas: Vec<Option<u16>>,
    od: Vec<Option<OdValue>>,
    counters: [u16; 7],
    counters_read: bool,
    /// The last failed request: why, and when it happened.
    gone: Option<String>,
    last_failure: Option<String>,
    refresh: Vec<Refresh>,
    next_refresh: usize,
    /// Sample times of the last second, for the achieved rate.
    sample_times: std::collections::VecDeque<Instant>,
}

impl RemoteDrive {
    fn new(master: Master) -> Self {
        let mut refresh = vec![Refresh::Pas];
        refresh.extend((0..COUNTER_SUBS.len()).map(Refresh::Counter));
        refresh.extend(
            TABLE
                .iter()
                .enumerate()
                .filter(|(_, e)| e.access().readable() && e.data_type() != DataType::Str)
                .map(|(i, _)| Refresh::Entry(i)),
        );
        Self {
            master,
            log: ExceptionLog::new(),
            statusword: 0,
            monitor: vec![0; usize::from(MONITOR_WORDS)],
            low_first: false,
            pas: vec![None; PA_COUNT],
            od: TABLE
                .iter()
                .map(|e| match (e.access(), e.data_type()) {
                    (Access::Wo, _) => Some(OdValue::Text("write-only".into())),
                    (_, DataType::Str) => Some(OdValue::Text("(read with 0x2B/0x0E)".into())),
                    _ => None,
                })
                .collect(),
            counters: [0; 7],
            counters_read: false,
            gone: Some("connecting".into()),
            last_failure: None,
            refresh,
            next_refresh: 0,
            sample_times: Default::default(),
        }
    }

    /// Notes how a request went: exceptions in the log, failures as the
    /// drive gone (with the frames).
    fn note(&mut self, pdu: &Pdu, request: &[u8], reply: &[u8], answer: &Result<Answer, String>) {
        match answer {
            Ok(Answer::Exception(code)) => {
                self.log.record("master", pdu.function(), *code, true);
                self.gone = None;
            }
            Ok(Answer::Ok(_)) => self.gone = None,
            Ok(_) | Err(_) => {
                let why = match answer {
                    Err(w) => w.clone(),
                    _ => "a reply that does not answer the request".into(),
                };
                let mut text = format!("{why}; request {}", hex(request));
                if !reply.is_empty() {
                    text.push_str(&format!(", reply {}", hex(reply)));
                }
                self.gone = Some(text.clone());
                self.last_failure = Some(text);
            }
        }
    }

    fn read(&mut self, start: u16, quantity: u16) -> Result<Vec<u16>, Failure> {
        let r = self.master.read(start, quantity);
        match &r {
            Ok(_) => self.gone = None,
            Err(Failure::Exception { code, .. }) => {
                self.log.record("master", 0x03, *code, true);
                self.gone = None;
            }
            Err(f) => {
                self.gone = Some(f.to_string());
                self.last_failure = Some(f.to_string());
            }
        }
        r
    }

    fn sample(&mut self) -> bool {
        let read = self
            .read(0x0000, MONITOR_WORDS)
            .and_then(|m| Ok((m, self.read(STATUSWORD, 1)?)));
        let (m, sw) = match read {
            Ok(r) => r,
            // The drive has both registers: a refusal comes from a gateway
            // whose drive does not answer (0x0A / 0x0B), or another device.
            Err(f @ Failure::Exception { .. }) => {
                self.gone = Some(f.to_string());
                self.last_failure = Some(f.to_string());
                return false;
            }
            Err(_) => return false,
        };
        self.monitor = m;
        self.statusword = sw[0];
        let now = Instant::now();
        self.sample_times.push_back(now);
        while self
            .sample_times
            .front()
            .is_some_and(|t| now.duration_since(*t) > Duration::from_secs(1))
        {
            self.sample_times.pop_front();
        }
        true
    }

    /// Samples taken in the last second.
    fn rate(&self) -> usize {
        let now = Instant::now();
        self.sample_times
            .iter()
            .filter(|t| now.duration_since(**t) <= Duration::from_secs(1))
            .count()
    }

    fn word32(&self, low: usize) -> i64 {
        i64::from((u32::from(self.monitor[low + 1]) << 16 | u32::from(self.monitor[low])) as i32)
    }

    fn has_following_error(&self) -> bool {
        position(FOLLOWING_ERROR).is_some()
    }

    /// The scope sample: position, velocity, following error, statusword.
    fn scope(&self) -> [Option<i64>; 4] {
        [
            Some(self.word32(0x01)),
            Some(i64::from(self.monitor[0x00] as i16)),
            self.has_following_error().then(|| self.word32(0x05)),
            Some(i64::from(self.statusword)),
        ]
    }

    fn refresh_one(&mut self) {
        let item = self.refresh[self.next_refresh % self.refresh.len()];
        self.next_refresh = (self.next_refresh + 1) % self.refresh.len();
        match item {
            Refresh::Pas => {
                if let Ok(p) = self.read(crate::virtual_drive::registers::PA_BASE, PA_COUNT as u16)
                {
                    self.pas = p.into_iter().map(Some).collect();
                }
            }
            Refresh::Counter(i) => {
                if let Ok(v) = self.master.diagnostic(COUNTER_SUBS[i]) {
                    self.counters[i] = v;
                    self.counters_read |= i == COUNTER_SUBS.len() - 1;
                }
            }
            Refresh::Entry(i) => {
                let e = &TABLE[i];
                let wide = matches!(e.data_type(), DataType::U32 | DataType::I32);
                if let Ok(w) = self.read(e.index(), if wide { 2 } else { 1 }) {
                    let raw = if wide {
                        let (hi, lo) = if self.low_first {
                            (w[1], w[0])
                        } else {
                            (w[0], w[1])
                        };
                        u32::from(hi) << 16 | u32::from(lo)
                    } else {
                        u32::from(w[0])
                    };
                    let v = match e.data_type() {
                        DataType::I16 => i64::from(raw as u16 as i16),
                        DataType::I32 => i64::from(raw as i32),
                        _ => i64::from(raw),
                    };
                    if e.index() == WORD_ORDER {
                        self.low_first = v == 1;
                    }
                    self.od[i] = Some(OdValue::Number(v));
                }
            }
        }
    }

    fn link_json(&self) -> String {
        format!(
            "{{\"ok\":{},\"describe\":{},\"address\":{},\"rate\":{},\"error\":{},\"last_failure\":{}}}",
            self.gone.is_none(),
            quote(&self.master.describe()),
            self.master.unit,
            self.rate(),
            self.gone.as_deref().map_or("null".into(), quote),
            self.last_failure.as_deref().map_or("null".into(), quote),
        )
    }

    fn snapshot(&self) -> Snapshot<'_> {
        let m = &self.monitor;
        let inputs = m[0x0F];
        let c = &self.counters;
        let state = power_state(self.statusword).map_or("Unknown".into(), |s| format!("{s:?}"));
        Snapshot {
            address: self.master.unit,
            state: if self.gone.is_some() {
                "NotAnswering".into()
            } else {
                state
            },
            statusword: self.statusword,
            error_register: m[0x13] & 0x00FF,
            mode: i64::from(m[0x0A] as i16),
            position: self.word32(0x01),
            velocity: i64::from(m[0x00] as i16),
            following_error: self.has_following_error().then(|| self.word32(0x05)),
            listen_only: false,
            busy: false,
            switches: Switches::new(inputs & 1 != 0, inputs & 2 != 0, inputs & 4 != 0),
            axis: None,
            bus_counters: self.counters_read.then(|| Counters::from_reads(*c)),
            page_counters: Some(self.master.tally().as_counters()),
            exceptions: &self.log,
            od: self.od.clone(),
            pa: self.pas.clone(),
            link: Some(self.link_json()),
        }
    }
}

impl Remote for RemoteDrive {
    fn ctx(&mut self) -> Ctx {
        if let Ok(sw) = self.read(STATUSWORD, 1) {
            self.statusword = sw[0];
        }
        Ctx {
            state: power_state(self.statusword)
                .unwrap_or(modbus_drive::drive::PowerState::NotReadyToSwitchOn),
            low_first: self.low_first,
        }
    }

    fn exchange(&mut self, pdu: &Pdu) -> (Vec<u8>, Vec<u8>, Result<Answer, String>) {
        // An EE operation answers once the flash is written (SPEC §9).
        let normal = self.master.timeout;
        if is_ee_operation(pdu) {
            self.master.timeout = normal.max(EE_TIMEOUT);
        }
        let (request, reply, answer) = self.master.exchange(pdu);
        self.master.timeout = normal;
        self.note(pdu, &request, &reply, &answer);
        (request, reply, answer)
    }
}

/// A write to the EE command register: 0x10 to 0x003A, or the old
/// format's 0x06 to 0x0000 (SPEC §9).
fn is_ee_operation(pdu: &Pdu) -> bool {
    let register = pdu.0.get(1..3).map(|b| u16::from_be_bytes([b[0], b[1]]));
    matches!(
        (pdu.function(), register),
        (0x10, Some(EE_REGISTER)) | (0x06, Some(0x0000))
    )
}

pub fn run(o: Commission) -> Result<(), String> {
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, Arc::clone(&stop))
            .map_err(|e| format!("cannot handle signal {sig}: {e}"))?;
    }
    let c = o.common;
    let timeout = c.timeout.unwrap_or(c.endpoint.default_timeout());
    let master = Master::new(c.endpoint, c.address, timeout);
    let mut port =
        WebPort::start(o.web, o.web_token, 1).map_err(|e| format!("--web {}: {e}", o.web))?;
    eprintln!("master: {} , address {}", master.describe(), master.unit);
    eprintln!("web: page on {}", port.url());
    println!("ready");
    let mut drive = RemoteDrive::new(master);
    let start = Instant::now();
    let mut next_state = start;
    let mut was_gone = false;
    while !stop.load(Ordering::Relaxed) {
        port.serve_remote(&mut drive);
        if drive.sample() {
            let t = start.elapsed().as_micros() as u64;
            port.publish_remote_sample(t, drive.scope());
            port.serve_remote(&mut drive);
            drive.refresh_one();
        }
        let gone = drive.gone.is_some();
        if gone != was_gone {
            match &drive.gone {
                Some(why) => eprintln!("drive {}: gone: {why}", drive.master.unit),
                None => eprintln!("drive {}: answering", drive.master.unit),
            }
            was_gone = gone;
        }
        if Instant::now() >= next_state || gone {
            let period = drive.rate().max(1) as u64;
            port.publish_remote_state(&drive.snapshot(), 1000 / period);
            next_state = Instant::now() + STATE_PERIOD;
        }
        if gone {
            // keep the page's commands answered while waiting
            let until = Instant::now() + RETRY;
            while Instant::now() < until && !stop.load(Ordering::Relaxed) {
                port.serve_remote(&mut drive);
                std::thread::sleep(Duration::from_millis(20));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ee_operations_are_told_from_other_writes() {
        assert!(is_ee_operation(&Pdu::write_multiple(0x003A, &[5])));
        assert!(is_ee_operation(&Pdu::write_single(0x0000, 1)));
        assert!(!is_ee_operation(&Pdu::write_single(0x003A, 1)));
        assert!(!is_ee_operation(&Pdu::write_multiple(0x6040, &[1])));
        assert!(!is_ee_operation(&Pdu(vec![0x10])));
    }
}
