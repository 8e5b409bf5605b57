//! stderr: log lines and the status line. On a terminal the status line is
//! redrawn in place and log lines scroll above it; elsewhere (a pipe, a log
//! file, the e2e tests) it is printed as a normal line when it changed, at
//! most once a second, so logs stay readable.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

pub struct Console {
    tty: bool,
    enabled: bool,
    start: Instant,
    status: String,
    status_shown: bool,
    last_draw: Option<Instant>,
    last_printed: String,
}

impl Console {
    pub fn new(status_line: bool) -> Self {
        Self {
            tty: std::io::stderr().is_terminal(),
            enabled: status_line,
            start: Instant::now(),
            status: String::new(),
            status_shown: false,
            last_draw: None,
            last_printed: String::new(),
        }
    }

    /// A log line, time-stamped in seconds since start.
    pub fn log(&mut self, msg: &str) {
        let t = self.start.elapsed().as_secs_f64();
        let mut e = std::io::stderr().lock();
        if self.tty && self.status_shown {
            let _ = write!(e, "\r\x1b[K");
        }
        let _ = writeln!(e, "[{t:9.3}] {msg}");
        if self.tty && self.status_shown {
            let _ = write!(e, "{}", self.status);
        }
        let _ = e.flush();
    }

    /// New status text; drawn if due.
    pub fn status(&mut self, text: String) {
        if !self.enabled {
            return;
        }
        self.status = text;
        let period = if self.tty {
            Duration::from_millis(200)
        } else {
            Duration::from_secs(1)
        };
        let due = self.last_draw.is_none_or(|t| t.elapsed() >= period);
        if !due {
            return;
        }
        let mut e = std::io::stderr().lock();
        if self.tty {
            let _ = write!(e, "\r\x1b[K{}", self.status);
            self.status_shown = true;
        } else if self.status != self.last_printed {
            let _ = writeln!(e, "status: {}", self.status);
            self.last_printed.clone_from(&self.status);
        }
        let _ = e.flush();
        self.last_draw = Some(Instant::now());
    }

    /// Leaves the status line (on a terminal) so later output starts clean.
    pub fn finish(&mut self) {
        if self.tty && self.status_shown {
            eprintln!();
            self.status_shown = false;
        }
    }
}
