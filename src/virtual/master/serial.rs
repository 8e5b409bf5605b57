//! RTU over a serial port (a USB–RS485 adapter, or a pseudo-terminal):
//! the port set raw at the chosen baud and character format, one request
//! written, the reply read until its length is complete (from its function
//! code and byte count) or the line stays silent.

use std::fs::{File, OpenOptions};
use std::io::{self, ErrorKind, Read, Write};
use std::os::fd::AsFd;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::termios::{
    cfmakeraw, cfsetspeed, tcflush, tcgetattr, tcsetattr, BaudRate, ControlFlags, FlushArg, SetArg,
};

use super::{LineSpec, Link};
use crate::virtual_drive::web::Pdu;

/// Silence after the last byte that ends a reply whose length the master
/// cannot tell in advance (a USB adapter delivers bytes in bursts, so the
/// line's own t3.5 is too short to judge from the host).
const END_SILENCE: Duration = Duration::from_millis(20);

pub struct Serial {
    port: File,
    line: LineSpec,
    /// When the last reply ended (if it was not silence): the next request
    /// waits t3.5 after it.
    last_rx: Option<Instant>,
    /// What was read away before the last request, and skipped before
    /// its reply.
    stale: Vec<u8>,
}

/// A port refused a character format (said once a run: a scan reopens
/// the port often).
static WARNED: AtomicBool = AtomicBool::new(false);

fn baud_rate(baud: u32) -> io::Result<BaudRate> {
    Ok(match baud {
        9600 => BaudRate::B9600,
        19200 => BaudRate::B19200,
        38400 => BaudRate::B38400,
        57600 => BaudRate::B57600,
        115200 => BaudRate::B115200,
        _ => return Err(io::Error::other(format!("unsupported baud {baud}"))),
    })
}

impl Serial {
    pub fn open(path: &Path, line: LineSpec) -> io::Result<Self> {
        let port = OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(nix::libc::O_NOCTTY | nix::libc::O_NONBLOCK)
            .open(path)?;
        let mut s = Self {
            port,
            line,
            last_rx: None,
            stale: Vec::new(),
        };
        s.configure(line)?;
        Ok(s)
    }

    fn configure(&mut self, line: LineSpec) -> io::Result<()> {
        let fd = self.port.as_fd();
        let mut t = tcgetattr(fd).map_err(io::Error::from)?;
        cfmakeraw(&mut t);
        cfsetspeed(&mut t, baud_rate(line.baud)?).map_err(io::Error::from)?;
        let c = &mut t.control_flags;
        c.remove(ControlFlags::PARENB | ControlFlags::PARODD | ControlFlags::CSTOPB);
        c.insert(ControlFlags::CS8 | ControlFlags::CLOCAL | ControlFlags::CREAD);
        match line.format {
            1 => c.insert(ControlFlags::PARENB),
            2 => c.insert(ControlFlags::PARENB | ControlFlags::PARODD),
            3 => c.insert(ControlFlags::CSTOPB),
            _ => {}
        }
        if let Err(e) = tcsetattr(fd, SetArg::TCSANOW, &t) {
            if e != nix::errno::Errno::EINVAL || line.format == 0 {
                return Err(e.into());
            }
            // Some pseudo-terminals refuse parity and stop-bit settings;
            // their bytes carry no character format, so the request gets
            // through as the drive expects it either way.
            let c = &mut t.control_flags;
            c.remove(ControlFlags::PARENB | ControlFlags::PARODD | ControlFlags::CSTOPB);
            tcsetattr(fd, SetArg::TCSANOW, &t).map_err(io::Error::from)?;
            if !WARNED.swap(true, Ordering::Relaxed) {
                eprintln!(
                    "serial: the port refuses {line}'s character format; it is sent as 8N1 \
                     on this side"
                );
            }
        }
        self.line = line;
        Ok(())
    }

    /// Waits up to `timeout` for input; false on timeout.
    fn wait(&self, timeout: Duration) -> io::Result<bool> {
        let ms = u16::try_from(timeout.as_millis().max(1)).unwrap_or(u16::MAX);
        let mut fds = [PollFd::new(self.port.as_fd(), PollFlags::POLLIN)];
        let n = poll(&mut fds, PollTimeout::from(ms)).map_err(io::Error::from)?;
        if n == 0 {
            return Ok(false);
        }
        let ev = fds[0].revents().unwrap_or(PollFlags::empty());
        if ev.intersects(PollFlags::POLLHUP | PollFlags::POLLERR | PollFlags::POLLNVAL)
            && !ev.contains(PollFlags::POLLIN)
        {
            return Err(io::Error::new(ErrorKind::BrokenPipe, "the line hung up"));
        }
        Ok(true)
    }
}

/// Where in `buf` a reply from `unit` to `function` can start (its end
/// if nowhere yet).
fn reply_start(buf: &[u8], unit: u8, function: u8) -> usize {
    (0..buf.len())
        .find(|&i| {
            buf[i] == unit
                && buf
                    .get(i + 1)
                    .is_none_or(|&f| f == function || f == function | 0x80)
        })
        .unwrap_or(buf.len())
}

/// The length of the reply frame that starts with `buf`, once it can be
/// told (Modbus Application Protocol §6: each function's reply layout).
fn reply_len(buf: &[u8]) -> Option<usize> {
    let f = *buf.get(1)?;
    if f & 0x80 != 0 {
        return Some(5);
    }
    match f {
        0x03 | 0x04 => buf.get(2).map(|&n| 5 + usize::from(n)),
        0x05 | 0x06 | 0x08 | 0x0F | 0x10 => Some(8),
        _ => None,
    }
}

impl Link for Serial {
    fn stale(&self) -> &[u8] {
        &self.stale
    }

    fn set_line(&mut self, line: LineSpec) -> io::Result<()> {
        self.configure(line)
    }

    fn exchange(
        &mut self,
        unit: u8,
        pdu: &Pdu,
        timeout: Duration,
    ) -> io::Result<(Vec<u8>, Vec<u8>)> {
        let frame = pdu.frame(unit);
        // The line's t3.5 between the last reply and this request.
        if let Some(t) = self.last_rx {
            let gap = self.line.t35();
            let since = t.elapsed();
            if since < gap {
                std::thread::sleep(gap - since);
            }
        }
        // Stale bytes would be read as this request's reply: a late reply to
        // a request that timed out, or another master's traffic (an RS-485
        // master hears the whole bus). Read them away too: some ports
        // (pseudo-terminals of some kernels) ignore the flush.
        let _ = tcflush(self.port.as_fd(), FlushArg::TCIFLUSH);
        let mut junk = [0u8; 256];
        self.stale.clear();
        while let Ok(n @ 1..) = self.port.read(&mut junk) {
            self.stale.extend_from_slice(&junk[..n]);
        }
        self.port.write_all(&frame)?;
        // The reply cannot start before the request has left the wire.
        let mut deadline = Instant::now() + self.line.time_of(frame.len()) + timeout;
        let mut reply = Vec::new();
        let mut chunk = [0u8; 256];
        loop {
            let known = reply_len(&reply);
            if known.is_some_and(|len| reply.len() >= len) {
                break;
            }
            let now = Instant::now();
            let wait = if known.is_none() && reply.len() >= 5 {
                END_SILENCE
            } else if now >= deadline {
                break;
            } else {
                deadline - now
            };
            if !self.wait(wait)? {
                break;
            }
            match self.port.read(&mut chunk) {
                Ok(0) => return Err(io::Error::new(ErrorKind::BrokenPipe, "the line closed")),
                Ok(k) => {
                    reply.extend_from_slice(&chunk[..k]);
                    // A reply starts with the address asked and the
                    // function (or its exception); bytes before it are
                    // other traffic on the bus, e.g. a late reply.
                    let start = reply_start(&reply, unit, pdu.function());
                    self.stale.extend(reply.drain(..start));
                    deadline = deadline.max(Instant::now() + END_SILENCE);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => {}
                Err(e) => return Err(e),
            }
        }
        // After silence the line has been quiet long enough already.
        self.last_rx = (!reply.is_empty()).then(Instant::now);
        Ok((frame, reply))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::os::fd::OwnedFd;

    /// A pty: the master's port at its slave end, the "drive" at its
    /// master end.
    fn line() -> (Serial, File, OwnedFd) {
        let p = nix::pty::openpty(None, None).unwrap();
        let path = nix::unistd::ttyname(&p.slave).unwrap();
        let port = Serial::open(&path, LineSpec::DEFAULT).unwrap();
        (port, File::from(p.master), p.slave)
    }

    /// Answers the next request with `reply` (after reading the request);
    /// gives back the request and the pty end (closing it would hang the
    /// line up before the reply is read).
    fn drive_answers(mut drive: File, reply: Vec<u8>) -> std::thread::JoinHandle<(Vec<u8>, File)> {
        std::thread::spawn(move || {
            let mut buf = [0u8; 64];
            let n = drive.read(&mut buf).unwrap();
            drive.write_all(&reply).unwrap();
            (buf[..n].to_vec(), drive)
        })
    }

    #[test]
    fn a_reply_is_read_whole_after_other_traffic_on_the_bus() {
        let (mut port, drive, _slave) = line();
        let request = Pdu::read(0x6041, 1);
        let mut reply = vec![0xE5, 0x07];
        reply.extend(Pdu(vec![0x03, 0x02, 0x00, 0x60]).frame(1));
        let t = drive_answers(drive, reply);
        let (sent, got) = port
            .exchange(1, &request, Duration::from_millis(500))
            .unwrap();
        assert_eq!(t.join().unwrap().0, sent);
        assert_eq!(sent, request.frame(1));
        assert_eq!(got, Pdu(vec![0x03, 0x02, 0x00, 0x60]).frame(1));
    }

    #[test]
    fn silence_is_an_empty_reply_and_a_short_one_is_kept_as_it_came() {
        let (mut port, drive, _slave) = line();
        let request = Pdu::write_single(0x6040, 6);
        let (_, got) = port
            .exchange(1, &request, Duration::from_millis(50))
            .unwrap();
        assert!(got.is_empty());
        // a reply cut short: what came, after the silence that ended it
        let t = drive_answers(drive, vec![0x01, 0x06, 0x60]);
        let (_, got) = port
            .exchange(1, &request, Duration::from_millis(100))
            .unwrap();
        t.join().unwrap();
        assert_eq!(got, [0x01, 0x06, 0x60]);
    }

    #[test]
    fn a_reply_starts_at_its_address_and_function() {
        // a late reply from drive 1 whose data holds 0x02
        let late = [0x01, 0x03, 0x02, 0x1B, 0x94, 0xB3, 0x1B];
        assert_eq!(reply_start(&late, 2, 0x03), late.len());
        assert_eq!(reply_start(&[0x01, 0x03, 0x02, 0x03, 0x02], 2, 0x03), 2);
        assert_eq!(reply_start(&[0xE5, 0x02, 0x83, 0x02], 2, 0x03), 1);
        // the address alone may start one: the next byte decides
        assert_eq!(reply_start(&[0xE5, 0x02], 2, 0x03), 1);
    }

    #[test]
    fn reply_lengths_follow_the_function_code() {
        assert_eq!(reply_len(&[1]), None);
        assert_eq!(reply_len(&[1, 0x83]), Some(5));
        assert_eq!(reply_len(&[1, 0x03]), None);
        assert_eq!(reply_len(&[1, 0x03, 4]), Some(9));
        assert_eq!(reply_len(&[1, 0x06]), Some(8));
        assert_eq!(reply_len(&[1, 0x10]), Some(8));
        assert_eq!(reply_len(&[1, 0x2B]), None);
    }
}
