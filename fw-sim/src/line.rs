//! The byte streams that stand in for the RS-485 line, as on the virtual
//! drive: TCP connections (raw RTU bytes) and a pseudo-terminal. Bytes from
//! a master reach the USART's RX at the USART's own baud rate and character
//! format; a pause between two chunks of input is line silence. Replies are
//! handed over as their characters leave the emulated wire, and only if the
//! board's RS-485 driver was enabled (DE high) for the whole character.

use std::fs::File;
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::os::fd::{AsFd, OwnedFd};
use std::path::PathBuf;
use std::time::Duration;

use nix::poll::{poll, PollFd, PollFlags, PollTimeout};

pub struct Line {
    listeners: Vec<TcpListener>,
    conns: Vec<TcpStream>,
    pty: Option<(File, OwnedFd, Option<PathBuf>)>,
}

impl Line {
    pub fn new(tcp: &[SocketAddr], pty_link: Option<&PathBuf>) -> std::io::Result<Self> {
        let mut listeners = Vec::new();
        for a in tcp {
            let l = TcpListener::bind(a)?;
            l.set_nonblocking(true)?;
            eprintln!("tcp: listening on {}", l.local_addr()?);
            listeners.push(l);
        }
        let pty = match pty_link {
            Some(link) => {
                let p = nix::pty::openpty(None, None).map_err(std::io::Error::from)?;
                let mut t = nix::sys::termios::tcgetattr(&p.slave).map_err(std::io::Error::from)?;
                nix::sys::termios::cfmakeraw(&mut t);
                nix::sys::termios::tcsetattr(&p.slave, nix::sys::termios::SetArg::TCSANOW, &t)
                    .map_err(std::io::Error::from)?;
                let path = nix::unistd::ttyname(&p.slave).map_err(std::io::Error::from)?;
                let fl = nix::fcntl::fcntl(p.master.as_fd(), nix::fcntl::FcntlArg::F_GETFL)
                    .map_err(std::io::Error::from)?;
                let fl = nix::fcntl::OFlag::from_bits_truncate(fl) | nix::fcntl::OFlag::O_NONBLOCK;
                nix::fcntl::fcntl(p.master.as_fd(), nix::fcntl::FcntlArg::F_SETFL(fl))
                    .map_err(std::io::Error::from)?;
                if std::fs::symlink_metadata(link).is_ok_and(|m| m.file_type().is_symlink()) {
                    std::fs::remove_file(link)?;
                }
                std::os::unix::fs::symlink(&path, link)?;
                eprintln!("pty: {} (link {})", path.display(), link.display());
                Some((File::from(p.master), p.slave, Some(link.clone())))
            }
            None => None,
        };
        Ok(Self {
            listeners,
            conns: Vec::new(),
            pty,
        })
    }

    /// Waits up to `timeout` for input; returns the chunks that arrived.
    pub fn poll(&mut self, timeout: Duration) -> Vec<Vec<u8>> {
        let ms = timeout.as_micros().div_ceil(1000).min(1000) as u16;
        {
            let mut fds: Vec<PollFd> = Vec::new();
            for l in &self.listeners {
                fds.push(PollFd::new(l.as_fd(), PollFlags::POLLIN));
            }
            for c in &self.conns {
                fds.push(PollFd::new(c.as_fd(), PollFlags::POLLIN));
            }
            if let Some((m, _, _)) = &self.pty {
                fds.push(PollFd::new(m.as_fd(), PollFlags::POLLIN));
            }
            if ms > 0 {
                let _ = poll(&mut fds, PollTimeout::from(ms));
            }
        }
        for l in &self.listeners {
            while let Ok((s, _)) = l.accept() {
                let _ = s.set_nonblocking(true);
                let _ = s.set_nodelay(true);
                self.conns.push(s);
            }
        }
        let mut chunks = Vec::new();
        let mut buf = [0u8; 1024];
        self.conns.retain_mut(|c| loop {
            match c.read(&mut buf) {
                Ok(0) => return false,
                Ok(n) => chunks.push(buf[..n].to_vec()),
                Err(e) if e.kind() == ErrorKind::WouldBlock => return true,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => return false,
            }
        });
        if let Some((m, _, _)) = &mut self.pty {
            while let Ok(n) = m.read(&mut buf) {
                if n == 0 {
                    break;
                }
                chunks.push(buf[..n].to_vec());
            }
        }
        chunks
    }

    pub fn send(&mut self, bytes: &[u8]) {
        self.conns.retain_mut(|c| c.write_all(bytes).is_ok());
        if let Some((m, _, _)) = &mut self.pty {
            let _ = m.write_all(bytes);
        }
    }
}

impl Drop for Line {
    fn drop(&mut self) {
        if let Some((_, _, Some(l))) = &self.pty {
            let _ = std::fs::remove_file(l);
        }
    }
}
