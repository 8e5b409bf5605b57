//! Who may use the page: the `Host` a request names, and the access token.
//!
//! - DNS rebinding: a foreign site's name made to resolve to this machine
//!   makes that site's script same-origin with the page, so a browser lets
//!   it read and post at will. The browser still sends the foreign *name*
//!   in `Host`, and a name is all a rebinding can use: an address literal
//!   cannot be rebound. So a request must name the address served (any
//!   address literal when bound to all of them), a loopback address, or
//!   `localhost`; anything else gets 403. The port is not compared: an SSH
//!   tunnel or a proxy in front changes it, and it plays no part in
//!   rebinding.
//! - Beyond loopback, anyone who reaches the port could move the axis, so
//!   a token is then required (`--web-token`, or a random one printed in
//!   the page's URL, as Jupyter does). It comes in the query (`token=`),
//!   the header `X-Modbus-Drive-Token`, or the cookie the page's URL sets
//!   (`SameSite=Strict`, so a foreign site's request does not carry it).

use std::fs::File;
use std::io::Read;
use std::net::{IpAddr, SocketAddr};

/// The header a script may send the token in.
pub const TOKEN_HEADER: &str = "X-Modbus-Drive-Token";
/// Shortest token `--web-token` accepts: a guessable one guards nothing.
pub const MIN_TOKEN_LEN: usize = 16;

/// Whether `v` can be a `--web-token`: long enough, and URL-safe, since
/// it goes into a URL and a cookie as it is.
pub fn token_is_valid(v: &str) -> bool {
    let safe = |c: char| c.is_ascii_alphanumeric() || "-_.~".contains(c);
    v.len() >= MIN_TOKEN_LEN && v.chars().all(safe)
}

/// Why a request was refused.
#[derive(Debug, PartialEq, Eq)]
pub enum Refusal {
    /// `Host` missing or naming another site: 403.
    Host,
    /// No token, or a wrong one: 401.
    Token,
}

pub struct Guard {
    served: SocketAddr,
    token: Option<String>,
}

impl Guard {
    /// `token`: the one given on the command line; without one, a random
    /// token is made when `served` is not a loopback address.
    pub fn new(served: SocketAddr, token: Option<String>) -> std::io::Result<Self> {
        let token = match token {
            Some(t) => Some(t),
            None if served.ip().is_loopback() => None,
            None => Some(random_token()?),
        };
        Ok(Self { served, token })
    }

    pub fn token(&self) -> Option<&str> {
        self.token.as_deref()
    }

    /// The cookie's name: per port, so that two drives on one machine do
    /// not overwrite each other's.
    pub fn cookie_name(&self) -> String {
        format!("modbus_drive_token_{}", self.served.port())
    }

    /// Checks a request's `Host` header and token (from its query `token`
    /// value, `X-Modbus-Drive-Token` header or `Cookie` header).
    pub fn check(
        &self,
        host: Option<&str>,
        query_token: Option<&str>,
        header_token: Option<&str>,
        cookie: Option<&str>,
    ) -> Result<(), Refusal> {
        if !host.is_some_and(|h| self.host_allowed(h)) {
            return Err(Refusal::Host);
        }
        let Some(token) = &self.token else {
            return Ok(());
        };
        let name = self.cookie_name();
        let from_cookie = cookie.and_then(|c| {
            c.split(';')
                .filter_map(|kv| kv.trim().split_once('='))
                .find(|(k, _)| *k == name)
                .map(|(_, v)| v)
        });
        let offered = [query_token, header_token, from_cookie];
        if offered
            .into_iter()
            .flatten()
            .any(|t| same(t.as_bytes(), token.as_bytes()))
        {
            Ok(())
        } else {
            Err(Refusal::Token)
        }
    }

    /// `Host` is `name[:port]` or `[v6][:port]`.
    fn host_allowed(&self, host: &str) -> bool {
        let host = host.trim();
        let name = if let Some(rest) = host.strip_prefix('[') {
            match rest.split_once(']') {
                Some((v6, _)) => v6,
                None => return false,
            }
        } else {
            host.rsplit_once(':').map_or(host, |(n, _)| n)
        };
        if name.eq_ignore_ascii_case("localhost") {
            return true;
        }
        match name.parse::<IpAddr>() {
            Ok(ip) => {
                ip == self.served.ip() || ip.is_loopback() || self.served.ip().is_unspecified()
            }
            Err(_) => false,
        }
    }
}

/// Compares without stopping at the first difference, so the time taken
/// does not tell how much of a guess was right.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// 128 bits from the kernel's random source, as hex.
fn random_token() -> std::io::Result<String> {
    let mut bytes = [0u8; 16];
    File::open("/dev/urandom")?.read_exact(&mut bytes)?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn guard(addr: &str, token: Option<&str>) -> Guard {
        Guard::new(addr.parse().unwrap(), token.map(String::from)).unwrap()
    }

    #[test]
    fn a_foreign_host_name_is_refused_an_address_or_localhost_is_not() {
        let g = guard("127.0.0.1:8080", None);
        for ok in [
            "127.0.0.1:8080",
            "localhost:8080",
            "LOCALHOST",
            "127.0.0.1:9000",
            "[::1]:80",
        ] {
            assert_eq!(g.check(Some(ok), None, None, None), Ok(()), "{ok}");
        }
        for bad in [
            "evil.example:8080",
            "127.0.0.1.nip.io:8080",
            "localhost.evil.example",
            "10.0.0.1:8080",
            "[::1",
            "",
        ] {
            assert_eq!(
                g.check(Some(bad), None, None, None),
                Err(Refusal::Host),
                "{bad}"
            );
        }
        assert_eq!(g.check(None, None, None, None), Err(Refusal::Host));
        let all = guard("0.0.0.0:8080", Some("0123456789abcdef"));
        let t = Some("0123456789abcdef");
        assert_eq!(all.check(Some("192.168.1.5:8080"), t, None, None), Ok(()));
        assert_eq!(
            all.check(Some("drive.evil.example"), t, None, None),
            Err(Refusal::Host)
        );
        let one = guard("192.168.1.5:8080", Some("0123456789abcdef"));
        assert_eq!(one.check(Some("192.168.1.5:8080"), t, None, None), Ok(()));
        assert_eq!(
            one.check(Some("192.168.1.6:8080"), t, None, None),
            Err(Refusal::Host)
        );
    }

    #[test]
    fn beyond_loopback_a_token_is_made_and_required() {
        let g = guard("0.0.0.0:8080", None);
        let token = g.token().expect("a random token").to_string();
        assert_eq!(token.len(), 32);
        assert_ne!(guard("0.0.0.0:8080", None).token(), Some(token.as_str()));
        let host = Some("10.1.1.1:8080");
        assert_eq!(g.check(host, None, None, None), Err(Refusal::Token));
        assert_eq!(
            g.check(host, Some("wrong"), Some(""), Some("a=b")),
            Err(Refusal::Token)
        );
        let mut near = token.clone();
        near.pop();
        assert_eq!(g.check(host, Some(&near), None, None), Err(Refusal::Token));
        assert_eq!(g.check(host, Some(&token), None, None), Ok(()));
        assert_eq!(g.check(host, None, Some(&token), None), Ok(()));
        let cookie = format!("x=1; modbus_drive_token_8080={token}");
        assert_eq!(g.check(host, None, None, Some(&cookie)), Ok(()));
        // another port's cookie is another drive's
        let other = format!("modbus_drive_token_8081={token}");
        assert_eq!(g.check(host, None, None, Some(&other)), Err(Refusal::Token));
        // loopback: no token unless one is given
        assert_eq!(guard("127.0.0.1:8080", None).token(), None);
        let given = guard("127.0.0.1:8080", Some("0123456789abcdef"));
        assert_eq!(
            given.check(Some("localhost"), None, None, None),
            Err(Refusal::Token)
        );
    }
}
