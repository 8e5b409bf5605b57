//! Byte streams that stand in for the RS-485 line: a pseudo-terminal and
//! TCP connections. Each carries raw RTU frames (same bytes, same CRC); the
//! framing itself is the core's [`modbus_drive::rtu::FrameAssembler`]'s job.
//!
//! All file descriptors are non-blocking; the event loop (`run.rs`) polls
//! them and calls `read` / `flush` when they are ready.

use std::fs::File;
use std::io::{self, ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::path::{Path, PathBuf};

use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};

/// The pseudo-terminal: we keep the master, serial tools open the slave.
pub struct Pty {
    master: File,
    /// Held open for our whole life: while any slave descriptor is open the
    /// master never reads EIO, so masters may close and reopen the port, and
    /// the raw mode set here stays in force between them.
    _slave: OwnedFd,
    pub path: PathBuf,
    link: Option<PathBuf>,
}

impl Pty {
    /// The pty and its `--pty-link`; the message says which failed.
    pub fn open(link: Option<&Path>) -> Result<Self, String> {
        let mut pty =
            Self::open_pty().map_err(|e| format!("cannot open a pseudo-terminal: {e}"))?;
        if let Some(l) = link {
            make_link(&pty.path, l)?;
            pty.link = Some(l.to_path_buf());
        }
        Ok(pty)
    }

    fn open_pty() -> io::Result<Self> {
        let pty = nix::pty::openpty(None, None).map_err(io::Error::from)?;
        // Raw mode on the slave: no echo, no CR/LF translation, no signals —
        // RTU is binary. Masters set their own mode on open as well.
        let mut t = tcgetattr(&pty.slave).map_err(io::Error::from)?;
        cfmakeraw(&mut t);
        tcsetattr(&pty.slave, SetArg::TCSANOW, &t).map_err(io::Error::from)?;
        let path = nix::unistd::ttyname(&pty.slave).map_err(io::Error::from)?;
        set_nonblocking(pty.master.as_fd())?;
        Ok(Self {
            master: File::from(pty.master),
            _slave: pty.slave,
            path,
            link: None,
        })
    }

    pub fn fd(&self) -> BorrowedFd<'_> {
        self.master.as_fd()
    }
}

impl Drop for Pty {
    fn drop(&mut self) {
        // Remove the symlink only if it still points at our pty.
        if let Some(l) = &self.link {
            if std::fs::read_link(l).ok().as_deref() == Some(self.path.as_path()) {
                let _ = std::fs::remove_file(l);
            }
        }
    }
}

/// `--pty-link`: replaces an existing symlink (a stale one from an earlier
/// run), refuses to replace anything else: a file there may be the user's.
fn make_link(target: &Path, link: &Path) -> Result<(), String> {
    let at = |what: String| format!("--pty-link {}: {what}", link.display());
    match std::fs::symlink_metadata(link) {
        Ok(m) if m.file_type().is_symlink() => std::fs::remove_file(link)
            .map_err(|e| at(format!("cannot replace the old symlink: {e}")))?,
        Ok(m) => {
            let what = if m.is_dir() {
                "a directory"
            } else if m.is_file() {
                "a regular file"
            } else {
                "a special file"
            };
            return Err(at(format!(
                "{what} is there; the link replaces only a symlink (one left by an \
                 earlier run). Remove it or choose another path"
            )));
        }
        Err(e) if e.kind() == ErrorKind::NotFound => {}
        Err(e) => return Err(at(format!("cannot look at it: {e}"))),
    }
    std::os::unix::fs::symlink(target, link).map_err(|e| {
        let dir = link.parent().filter(|d| !d.as_os_str().is_empty());
        match dir {
            Some(d) if e.kind() == ErrorKind::NotFound => at(format!(
                "cannot make the link: directory {} does not exist",
                d.display()
            )),
            _ => at(format!("cannot make the link: {e}")),
        }
    })
}

fn set_nonblocking(fd: BorrowedFd<'_>) -> io::Result<()> {
    let flags = fcntl(fd, FcntlArg::F_GETFL).map_err(io::Error::from)?;
    let flags = OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK;
    fcntl(fd, FcntlArg::F_SETFL(flags)).map_err(io::Error::from)?;
    Ok(())
}

/// Why `flag ADDR` could not listen, with what to do about the usual
/// causes.
pub fn listen_error(flag: &str, addr: SocketAddr, e: &io::Error) -> String {
    let hint = match e.kind() {
        ErrorKind::AddrInUse => {
            "; another program, or another listener of this one, has that port: choose another \
             port, or port 0 for a free one"
        }
        ErrorKind::PermissionDenied if addr.port() < 1024 => {
            "; ports below 1024 (502 among them) need root or CAP_NET_BIND_SERVICE: \
             choose e.g. 5020"
        }
        ErrorKind::AddrNotAvailable => {
            "; no interface of this machine has that address (127.0.0.1: this machine \
             only, 0.0.0.0: every interface)"
        }
        _ => "",
    };
    format!("{flag} {addr}: cannot listen: {e}{hint}")
}

/// A listening TCP socket (`--tcp`, `--modbus-tcp`).
pub struct Listener {
    pub socket: TcpListener,
    pub addr: SocketAddr,
}

impl Listener {
    pub fn bind(addr: SocketAddr) -> io::Result<Self> {
        let socket = TcpListener::bind(addr)?;
        socket.set_nonblocking(true)?;
        let addr = socket.local_addr()?;
        Ok(Self { socket, addr })
    }

    /// The next pending connection, if any.
    pub fn accept(&self) -> io::Result<Option<(TcpStream, SocketAddr)>> {
        match self.socket.accept() {
            Ok((s, peer)) => {
                s.set_nonblocking(true)?;
                // A reply is one small write; send it now, not after Nagle's wait.
                s.set_nodelay(true)?;
                Ok(Some((s, peer)))
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => Ok(None),
            Err(e) => Err(e),
        }
    }
}

/// The byte stream of one line.
pub enum Stream {
    Pty(Pty),
    Tcp(TcpStream),
}

/// Result of draining a readable stream.
pub enum ReadOutcome {
    /// Bytes appended (possibly none).
    Data,
    /// The peer closed the connection (TCP only).
    Closed,
}

impl Stream {
    pub fn fd(&self) -> BorrowedFd<'_> {
        match self {
            Self::Pty(p) => p.fd(),
            Self::Tcp(s) => s.as_fd(),
        }
    }

    /// Reads what is available into `buf` (appending).
    pub fn read_available(&mut self, buf: &mut Vec<u8>) -> io::Result<ReadOutcome> {
        let mut chunk = [0u8; 1024];
        let mut total = 0;
        loop {
            let r = match self {
                Self::Pty(p) => p.master.read(&mut chunk),
                Self::Tcp(s) => s.read(&mut chunk),
            };
            match r {
                Ok(0) => {
                    return Ok(match self {
                        Self::Tcp(_) if total == 0 => ReadOutcome::Closed,
                        _ => ReadOutcome::Data,
                    })
                }
                Ok(n) => {
                    buf.extend_from_slice(&chunk[..n]);
                    total += n;
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(ReadOutcome::Data),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
    }

    /// Writes as much of `out` as the stream takes now and removes it from
    /// `out`. A reply is handed over in one `write` call, so it leaves as one
    /// burst unless the peer stopped reading.
    pub fn flush(&mut self, out: &mut Vec<u8>) -> io::Result<()> {
        while !out.is_empty() {
            let r = match self {
                Self::Pty(p) => p.master.write(out),
                Self::Tcp(s) => s.write(out),
            };
            match r {
                Ok(n) => {
                    out.drain(..n);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(()),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }
}
