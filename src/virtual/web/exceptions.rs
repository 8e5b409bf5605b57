//! The last exceptions a drive answered, on any port, for the page.

use std::collections::VecDeque;
use std::time::Instant;

/// Exceptions kept per drive.
const KEPT: usize = 12;

/// One refused request.
#[derive(Clone, Debug, PartialEq)]
pub struct Refusal {
    /// Counts every refusal since start (the page tells new ones apart).
    pub seq: u64,
    /// Seconds since start.
    pub time_s: f64,
    /// Where the request came from ("pty", "tcp …", "web").
    pub port: String,
    pub function: u8,
    /// The code as sent (after PA55).
    pub code: u8,
    /// False for a broadcast (refused without a reply).
    pub answered: bool,
}

#[derive(Clone, Debug)]
pub struct ExceptionLog {
    start: Instant,
    seq: u64,
    last: VecDeque<Refusal>,
}

impl ExceptionLog {
    /// Times are counted from now.
    pub fn new() -> Self {
        Self {
            start: Instant::now(),
            seq: 0,
            last: VecDeque::new(),
        }
    }

    pub fn record(&mut self, port: &str, function: u8, code: u8, answered: bool) {
        let time_s = self.start.elapsed().as_secs_f64();
        self.seq += 1;
        if self.last.len() == KEPT {
            self.last.pop_front();
        }
        self.last.push_back(Refusal {
            seq: self.seq,
            time_s,
            port: port.to_string(),
            function,
            code,
            answered,
        });
    }

    /// Newest last.
    pub fn iter(&self) -> impl Iterator<Item = &Refusal> {
        self.last.iter()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_newest_refusals() {
        let mut log = ExceptionLog::new();
        for i in 0..20u8 {
            log.record("web", 6, i, true);
        }
        let codes: Vec<u8> = log.iter().map(|r| r.code).collect();
        assert_eq!(codes, (8..20).collect::<Vec<_>>());
        assert_eq!(log.iter().last().map(|r| r.seq), Some(20));
    }
}
