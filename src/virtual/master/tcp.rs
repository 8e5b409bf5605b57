//! Modbus TCP (MBAP) to a gateway or a drive's Modbus TCP port: one
//! connection, one request at a time, the reply matched by its
//! transaction number. Framing is the core's (`modbus_drive::mbap`).

use std::io::{self, ErrorKind, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use modbus_drive::mbap::{encode_response, Decoder, Frame, Header, HEADER_LEN, MAX_ADU};

use super::{LineSpec, Link};
use crate::virtual_drive::web::Pdu;

/// Longest wait for the connection itself.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);

pub struct Tcp {
    stream: TcpStream,
    transaction: u16,
}

impl Tcp {
    pub fn connect(peer: &str) -> io::Result<Self> {
        let addr = peer
            .to_socket_addrs()?
            .next()
            .ok_or_else(|| io::Error::other(format!("{peer}: no address")))?;
        let stream = TcpStream::connect_timeout(&addr, CONNECT_TIMEOUT)?;
        stream.set_nodelay(true)?;
        Ok(Self {
            stream,
            transaction: 0,
        })
    }
}

impl Link for Tcp {
    fn set_line(&mut self, _line: LineSpec) -> io::Result<()> {
        // The gateway owns the serial line's settings.
        Ok(())
    }

    fn exchange(
        &mut self,
        unit: u8,
        pdu: &Pdu,
        timeout: Duration,
    ) -> io::Result<(Vec<u8>, Vec<u8>)> {
        self.transaction = self.transaction.wrapping_add(1);
        let t = self.transaction.to_be_bytes();
        // A request ADU has the layout of a response ADU: the core's
        // encoder writes it from a header with our transaction and unit.
        let header = Header::parse(&[t[0], t[1], 0, 0, 0, 0, unit]);
        let mut out = [0u8; MAX_ADU];
        let n = encode_response(&header, &pdu.0, &mut out);
        self.stream.write_all(&out[..n])?;
        let deadline = Instant::now() + timeout;
        let mut decoder = Decoder::new();
        let mut chunk = [0u8; MAX_ADU];
        loop {
            let now = Instant::now();
            if now >= deadline {
                return Ok((out[..n].to_vec(), Vec::new()));
            }
            self.stream.set_read_timeout(Some(deadline - now))?;
            let k = match self.stream.read(&mut chunk) {
                Ok(0) => {
                    return Err(io::Error::new(
                        ErrorKind::BrokenPipe,
                        "the server closed the connection",
                    ))
                }
                Ok(k) => k,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    return Ok((out[..n].to_vec(), Vec::new()))
                }
                Err(e) => return Err(e),
            };
            let mut input = &chunk[..k];
            while !input.is_empty() {
                let (used, frame) = decoder.feed(input);
                match frame {
                    Some(Frame::Request {
                        header: h,
                        pdu: reply,
                    }) if h.transaction() == self.transaction => {
                        let mut adu = h_bytes(&h);
                        adu.extend_from_slice(reply);
                        return Ok((out[..n].to_vec(), adu));
                    }
                    Some(Frame::BadLength(_)) => {
                        return Err(io::Error::other("the server sent a bad MBAP length"))
                    }
                    // a late reply to an earlier request, or another protocol
                    _ => {}
                }
                input = &input[used..];
                if used == 0 {
                    break;
                }
            }
        }
    }
}

fn h_bytes(h: &Header) -> Vec<u8> {
    let mut v = Vec::with_capacity(HEADER_LEN);
    v.extend_from_slice(&h.transaction().to_be_bytes());
    v.extend_from_slice(&h.protocol().to_be_bytes());
    v.extend_from_slice(&h.length().to_be_bytes());
    v.push(h.unit());
    v
}
