//! A small HTTP/1.1 server with every resource bounded, for a page that
//! may face a hostile network (one request per connection, then close).
//!
//! - One reader thread polls every connection whose request is not yet
//!   complete: a client that sends slowly (slow loris) costs a buffer, not
//!   a thread. A request head over [`Limits::head_bytes`], a body over
//!   [`Limits::body_bytes`], and a request not complete within
//!   [`Limits::request_time`] are answered 431 / 413 / 408 and closed.
//! - At most [`Limits::connections`] such connections: a new one closes
//!   the oldest waiting (the slowest sender) rather than being refused, so
//!   a crowd of stalled sockets cannot lock a real client out.
//! - Complete requests go to a fixed pool of [`Limits::workers`] threads
//!   through a queue of [`Limits::queue`]; when it is full the request is
//!   answered 503 at once.
//! - Answers are written with a timeout ([`Limits::write_time`]): a peer
//!   that does not read is dropped.

use std::collections::VecDeque;
use std::io::{self, ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::os::fd::AsFd;
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration, Instant};

use nix::poll::{poll, PollFd, PollFlags, PollTimeout};

#[derive(Clone, Copy, Debug)]
pub struct Limits {
    pub workers: usize,
    pub queue: usize,
    pub connections: usize,
    pub head_bytes: usize,
    pub body_bytes: usize,
    pub request_time: Duration,
    pub write_time: Duration,
}

/// The page's needs with a wide margin: a handful of requests a second
/// from each open page, heads of a few hundred bytes, no bodies.
pub const LIMITS: Limits = Limits {
    workers: 8,
    queue: 256,
    connections: 256,
    head_bytes: 8 * 1024,
    body_bytes: 4 * 1024,
    request_time: Duration::from_secs(5),
    write_time: Duration::from_secs(5),
};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    Get,
    Post,
    Other,
}

pub struct Request {
    method: Method,
    url: String,
    headers: Vec<(String, String)>,
    stream: TcpStream,
}

impl Request {
    pub fn method(&self) -> &Method {
        &self.method
    }

    pub fn url(&self) -> &str {
        &self.url
    }

    /// The first header named `name` (any case).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    pub fn respond(mut self, response: Response) -> io::Result<()> {
        response.write_to(&mut self.stream)
    }

    /// The connection, for an answer that streams (blocking, with the
    /// write timeout set).
    pub fn into_stream(self) -> TcpStream {
        self.stream
    }
}

pub struct Response {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Response {
    pub fn new(status: u16, content_type: &str, body: impl Into<Vec<u8>>) -> Self {
        Self {
            status,
            headers: vec![("Content-Type".into(), content_type.into())],
            body: body.into(),
        }
    }

    pub fn with_header(mut self, name: &str, value: &str) -> Self {
        self.headers.push((name.into(), value.into()));
        self
    }

    fn write_to(&self, w: &mut impl Write) -> io::Result<()> {
        let mut head = format!("HTTP/1.1 {} {}\r\n", self.status, reason(self.status));
        for (k, v) in &self.headers {
            head.push_str(&format!("{k}: {v}\r\n"));
        }
        head.push_str(&format!(
            "Content-Length: {}\r\nConnection: close\r\n\r\n",
            self.body.len()
        ));
        let mut all = head.into_bytes();
        all.extend_from_slice(&self.body);
        w.write_all(&all)?;
        w.flush()
    }
}

fn reason(status: u16) -> &'static str {
    match status {
        200 => "OK",
        400 => "Bad Request",
        401 => "Unauthorized",
        403 => "Forbidden",
        404 => "Not Found",
        408 => "Request Timeout",
        413 => "Content Too Large",
        414 => "URI Too Long",
        431 => "Request Header Fields Too Large",
        501 => "Not Implemented",
        503 => "Service Unavailable",
        _ => "",
    }
}

/// Starts the reader thread and the workers; `handler` runs on a worker
/// for each complete request.
pub fn spawn<H>(listener: TcpListener, limits: Limits, handler: H) -> io::Result<()>
where
    H: Fn(Request) + Send + Sync + 'static,
{
    listener.set_nonblocking(true)?;
    let (tx, rx) = mpsc::sync_channel::<Request>(limits.queue);
    let rx = Arc::new(Mutex::new(rx));
    let handler = Arc::new(handler);
    for i in 0..limits.workers {
        let rx = Arc::clone(&rx);
        let handler = Arc::clone(&handler);
        thread::Builder::new()
            .name(format!("web-worker-{i}"))
            .spawn(move || work(&rx, &*handler))?;
    }
    thread::Builder::new()
        .name("web-reader".into())
        .spawn(move || read_requests(&listener, limits, &tx))?;
    Ok(())
}

fn work<H: Fn(Request)>(rx: &Mutex<Receiver<Request>>, handler: &H) {
    loop {
        let next = rx
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .recv();
        match next {
            // a handler that panics loses its request, not the worker
            Ok(request) => {
                let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| handler(request)));
            }
            Err(_) => return,
        }
    }
}

/// A connection whose request is not complete yet.
struct Pending {
    stream: TcpStream,
    since: Instant,
    buf: Vec<u8>,
}

/// What the bytes so far make.
enum Parsed {
    Incomplete,
    Done(Method, String, Vec<(String, String)>),
    Refuse(u16, &'static str),
}

fn read_requests(listener: &TcpListener, limits: Limits, tx: &SyncSender<Request>) {
    let mut pending: VecDeque<Pending> = VecDeque::new();
    loop {
        let ready = {
            let mut fds = vec![PollFd::new(listener.as_fd(), PollFlags::POLLIN)];
            fds.extend(
                pending
                    .iter()
                    .map(|p| PollFd::new(p.stream.as_fd(), PollFlags::POLLIN)),
            );
            let wait = pending
                .front()
                .map_or(limits.request_time, |p| {
                    (p.since + limits.request_time).saturating_duration_since(Instant::now())
                })
                .as_millis()
                .clamp(1, 1000) as u16;
            match poll(&mut fds, PollTimeout::from(wait)) {
                Ok(_) => {}
                Err(nix::errno::Errno::EINTR) => continue,
                Err(_) => {
                    thread::sleep(Duration::from_millis(10));
                    continue;
                }
            }
            let flags = PollFlags::POLLIN | PollFlags::POLLHUP | PollFlags::POLLERR;
            fds.iter()
                .map(|f| f.revents().is_some_and(|r| r.intersects(flags)))
                .collect::<Vec<_>>()
        };
        // oldest first, so a removal does not shift what is still to read
        let mut done: Vec<usize> = Vec::new();
        for (i, p) in pending.iter_mut().enumerate() {
            if !ready[i + 1] {
                continue;
            }
            match read_more(p, limits) {
                None => {}
                Some(None) => done.push(i),
                Some(Some((method, url, headers))) => {
                    done.push(i);
                    let Ok(stream) = p.stream.try_clone() else {
                        continue;
                    };
                    let _ = stream.set_nonblocking(false);
                    let _ = stream.set_write_timeout(Some(limits.write_time));
                    let request = Request {
                        method,
                        url,
                        headers,
                        stream,
                    };
                    match tx.try_send(request) {
                        Ok(()) => {}
                        Err(TrySendError::Full(r)) => {
                            let _ =
                                r.respond(Response::new(503, "text/plain", "busy: try again\n"));
                        }
                        Err(TrySendError::Disconnected(_)) => return,
                    }
                }
            }
        }
        for i in done.into_iter().rev() {
            pending.remove(i);
        }
        let now = Instant::now();
        while pending
            .front()
            .is_some_and(|p| now >= p.since + limits.request_time)
        {
            if let Some(mut p) = pending.pop_front() {
                refuse(&mut p.stream, 408, "the request did not come in time\n");
            }
        }
        if ready[0] {
            accept_all(listener, limits, &mut pending);
        }
    }
}

fn accept_all(listener: &TcpListener, limits: Limits, pending: &mut VecDeque<Pending>) {
    loop {
        match listener.accept() {
            Ok((stream, _)) => {
                if stream.set_nonblocking(true).is_err() {
                    continue;
                }
                if pending.len() >= limits.connections {
                    // the oldest waiting is the slowest sender
                    pending.pop_front();
                }
                pending.push_back(Pending {
                    stream,
                    since: Instant::now(),
                    buf: Vec::new(),
                });
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => return,
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            // out of descriptors and the like: try again on the next wake
            Err(_) => return,
        }
    }
}

/// Reads what `p` sent. `None`: keep waiting; `Some(None)`: closed or
/// refused (answered); `Some(Some(..))`: a complete request.
#[allow(clippy::type_complexity)]
fn read_more(
    p: &mut Pending,
    limits: Limits,
) -> Option<Option<(Method, String, Vec<(String, String)>)>> {
    let mut chunk = [0u8; 2048];
    loop {
        match p.stream.read(&mut chunk) {
            Ok(0) => return Some(None),
            Ok(n) => p.buf.extend_from_slice(&chunk[..n]),
            Err(e) if e.kind() == ErrorKind::WouldBlock => break,
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(_) => return Some(None),
        }
        if p.buf.len() > limits.head_bytes + limits.body_bytes {
            break;
        }
    }
    match parse(&p.buf, limits) {
        Parsed::Incomplete => None,
        Parsed::Done(m, u, h) => Some(Some((m, u, h))),
        Parsed::Refuse(status, why) => {
            refuse(&mut p.stream, status, why);
            Some(None)
        }
    }
}

/// Best effort on a non-blocking socket: the answer is small and the
/// socket's buffer empty, so it goes out whole or the peer is gone.
fn refuse(stream: &mut TcpStream, status: u16, why: &str) {
    let _ = Response::new(status, "text/plain", why).write_to(stream);
}

fn parse(buf: &[u8], limits: Limits) -> Parsed {
    let Some(end) = buf.windows(4).position(|w| w == b"\r\n\r\n") else {
        if buf.len() > limits.head_bytes {
            return Parsed::Refuse(431, "request head too large\n");
        }
        return Parsed::Incomplete;
    };
    if end > limits.head_bytes {
        return Parsed::Refuse(431, "request head too large\n");
    }
    let Ok(head) = std::str::from_utf8(&buf[..end]) else {
        return Parsed::Refuse(400, "request head is not text\n");
    };
    let mut lines = head.split("\r\n");
    let mut first = lines.next().unwrap_or("").split(' ');
    let (Some(method), Some(url), Some(version), None) =
        (first.next(), first.next(), first.next(), first.next())
    else {
        return Parsed::Refuse(400, "bad request line\n");
    };
    if !version.starts_with("HTTP/1.") || !url.starts_with('/') {
        return Parsed::Refuse(400, "bad request line\n");
    }
    let mut headers = Vec::new();
    for line in lines {
        let Some((k, v)) = line.split_once(':') else {
            return Parsed::Refuse(400, "bad header line\n");
        };
        headers.push((k.trim().to_string(), v.trim().to_string()));
    }
    let get = |name: &str| {
        headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    };
    if get("Transfer-Encoding").is_some() {
        return Parsed::Refuse(501, "chunked bodies are not accepted\n");
    }
    let body = match get("Content-Length").map(str::parse::<usize>) {
        None => 0,
        Some(Ok(n)) => n,
        Some(Err(_)) => return Parsed::Refuse(400, "bad Content-Length\n"),
    };
    if body > limits.body_bytes {
        return Parsed::Refuse(413, "request body too large\n");
    }
    if buf.len() < end + 4 + body {
        return Parsed::Incomplete;
    }
    let method = match method {
        "GET" => Method::Get,
        "POST" => Method::Post,
        _ => Method::Other,
    };
    Parsed::Done(method, url.to_string(), headers)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parsed(raw: &str) -> Result<(Method, String, usize), u16> {
        match parse(raw.as_bytes(), LIMITS) {
            Parsed::Done(m, u, h) => Ok((m, u, h.len())),
            Parsed::Incomplete => Err(0),
            Parsed::Refuse(s, _) => Err(s),
        }
    }

    #[test]
    fn heads_parse_and_oversize_or_bad_ones_are_refused() {
        assert_eq!(
            parsed("GET /api/state HTTP/1.1\r\nHost: a\r\nX: y\r\n\r\n"),
            Ok((Method::Get, "/api/state".into(), 2))
        );
        assert_eq!(
            parsed("POST /api/cmd?d=0 HTTP/1.1\r\nHost: a\r\nContent-Length: 3\r\n\r\nabc"),
            Ok((Method::Post, "/api/cmd?d=0".into(), 2))
        );
        // the body is waited for
        assert_eq!(
            parsed("POST / HTTP/1.1\r\nContent-Length: 3\r\n\r\nab"),
            Err(0)
        );
        assert_eq!(parsed("GET / HTTP/1.1\r\nHost: a\r\n"), Err(0));
        let huge = format!("GET / HTTP/1.1\r\nX: {}\r\n", "a".repeat(9000));
        assert_eq!(parsed(&huge), Err(431));
        assert_eq!(
            parsed("POST / HTTP/1.1\r\nContent-Length: 5000\r\n\r\n"),
            Err(413)
        );
        assert_eq!(
            parsed("POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n"),
            Err(501)
        );
        for bad in [
            "GET / HTTP/1.1 x\r\n\r\n",
            "GET http://a/ HTTP/1.1\r\n\r\n",
            "GET / SPDY\r\n\r\n",
            "GET / HTTP/1.1\r\nno colon\r\n\r\n",
            "POST / HTTP/1.1\r\nContent-Length: -1\r\n\r\n",
        ] {
            assert_eq!(parsed(bad), Err(400), "{bad:?}");
        }
    }
}
