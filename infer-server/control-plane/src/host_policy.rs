//! The `Host` allowlist: the defence against DNS rebinding. A policy the control plane's
//! `Core` (`crate::core`) holds; the HTTP side applies it to every request
//! (`http::host::require_known_host`).
//!
//! A page of another site whose name the attacker re-binds to 127.0.0.1 talks to this server as
//! a same-origin page: its requests carry `Host: evil.test:8080` and `Origin: http://evil.test:8080`,
//! so an `Origin` check alone accepts them. The name in `Host` is what gives it away: the browser
//! writes there the name the page was loaded under. So every HTTP request (the page, `/api/*`, the
//! WebSocket upgrade, `/metrics`) must name this server by a name it knows, and only then is
//! `Origin` looked at. The known names are the loopback names and addresses, the address the
//! server is bound to (every IP literal when bound to 0.0.0.0 or `::`: the request reached one of
//! this machine's addresses), and the names given with `Config::allowed_hosts`
//! (`infer-server --allowed-host`, `HAPTICS_ALLOWED_HOSTS`).
//!
//! Why the page itself too, not only the calls that change something: under a foreign name the
//! page could be read and then the reads (status, model list, telemetry) made from it; refusing
//! it outright means a rebinding attack gets nothing, and a person typing a name the server does
//! not know gets an error that says which flag to set.
use std::net::{IpAddr, SocketAddr};

use crate::error::ControlError;

/// Which `Host` names this server answers to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HostPolicy {
    /// Extra names (lower case, no port), as configured.
    names: Vec<String>,
    /// The addresses the servers are bound to.
    bound: Vec<IpAddr>,
}

impl HostPolicy {
    pub fn new(bound: &[SocketAddr], extra: &[String]) -> Self {
        Self {
            names: extra.iter().map(|n| normalise(n)).collect(),
            bound: bound.iter().map(SocketAddr::ip).collect(),
        }
    }

    /// Whether `host` (a `Host` header value: a name or an IP literal, with or without a port)
    /// names this server. The port is not compared: an ssh tunnel or a published container port
    /// changes it, and a rebinding page cannot choose the name whatever the port.
    pub fn allows(&self, host: &str) -> bool {
        let Some(host) = parse_host(host) else {
            return false;
        };
        match host {
            Host::Name(name) => {
                let name = normalise(name);
                !name.is_empty() && (name == "localhost" || self.names.contains(&name))
            }
            Host::Ip(ip) => {
                ip.is_loopback()
                    || self
                        .bound
                        .iter()
                        .any(|b| b.is_unspecified() || *b == ip || same_v4(*b, ip))
            }
        }
    }

    /// Checks a request's `Host` (or, over HTTP/2, its `:authority`). A request that names no
    /// host at all does not come from a browser (browsers always send one) and passes.
    pub fn check(&self, host: Option<&str>) -> Result<(), ControlError> {
        match host {
            None => Ok(()),
            Some(h) if self.allows(h) => Ok(()),
            Some(h) => Err(ControlError::Forbidden(format!(
                "this server does not answer to the name {h:?} (a page re-bound to this address \
                 by DNS would send it); use 127.0.0.1 or localhost, or allow the name with \
                 infer-server --allowed-host NAME (or HAPTICS_ALLOWED_HOSTS)"
            ))),
        }
    }
}

/// An IPv4 address and its IPv4-mapped IPv6 form are the same address.
fn same_v4(a: IpAddr, b: IpAddr) -> bool {
    let v4 = |ip: IpAddr| match ip {
        IpAddr::V4(v) => Some(v),
        IpAddr::V6(v) => v.to_ipv4_mapped(),
    };
    v4(a).is_some() && v4(a) == v4(b)
}

fn normalise(name: &str) -> String {
    name.trim().trim_end_matches('.').to_ascii_lowercase()
}

/// What a `Host` value names, once its port is taken off.
#[derive(Debug, PartialEq, Eq)]
enum Host<'a> {
    Name(&'a str),
    Ip(IpAddr),
}

/// Parses a `Host` value strictly (RFC 9110's `uri-host [ ":" port ]`): `name`, `name:port`,
/// `1.2.3.4[:port]`, `[v6][:port]` (a bare IPv6 literal is taken whole too). Anything else
/// (`[::1]evil.test`, `localhost:`, `name:80x`, a byte outside letters, digits, `.`, `-`, `_`)
/// is `None`: refused, never read leniently as a name it merely starts with.
fn parse_host(host: &str) -> Option<Host<'_>> {
    let port_ok = |p: &str| !p.is_empty() && p.len() <= 5 && p.bytes().all(|b| b.is_ascii_digit());
    if let Some(rest) = host.strip_prefix('[') {
        let (inner, after) = rest.split_once(']')?;
        if !(after.is_empty() || after.strip_prefix(':').is_some_and(port_ok)) {
            return None;
        }
        return inner
            .parse::<std::net::Ipv6Addr>()
            .ok()
            .map(|v6| Host::Ip(v6.into()));
    }
    if let Ok(ip) = host.parse::<IpAddr>() {
        return Some(Host::Ip(ip));
    }
    let name = match host.rsplit_once(':') {
        Some((name, port)) if port_ok(port) => name,
        Some(_) => return None,
        None => host,
    };
    if let Ok(ip) = name.parse::<std::net::Ipv4Addr>() {
        return Some(Host::Ip(ip.into()));
    }
    let valid = !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'-' | b'_'));
    valid.then_some(Host::Name(name))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy(bound: &str, extra: &[&str]) -> HostPolicy {
        let extra: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
        HostPolicy::new(&[bound.parse().unwrap()], &extra)
    }

    #[test]
    fn loopback_names_and_the_bound_address_pass() {
        let p = policy("127.0.0.1:8080", &[]);
        for ok in [
            "127.0.0.1:8080",
            "127.0.0.1",
            "127.1.2.3:8080",
            "localhost:8080",
            "LOCALHOST",
            "localhost.:8080",
            "[::1]:8080",
            "[::1]",
            "127.0.0.1:9000",
        ] {
            assert!(p.allows(ok), "{ok}");
        }
        for bad in [
            "evil.test:8080",
            "evil.test",
            "localhost.evil.test:8080",
            "127.0.0.1.nip.io:8080",
            "10.0.0.5:8080",
            "",
            ":8080",
            "[::2]:8080",
            "0.0.0.0:8080",
            "[::1]evil.test",
            "[::1]evil.test:8080",
            "[::1]:80x",
            "localhost:",
            "localhost:8080:8080",
            "[127.0.0.1]:8080",
            "127.0.0.1 .evil.test",
            "localhost\u{e9}",
            "[::1",
        ] {
            assert!(!p.allows(bad), "{bad}");
        }
    }

    #[test]
    fn configured_names_and_bound_addresses_pass() {
        let p = policy("192.168.1.20:8080", &["Lab-PC", "lab-pc.example.org."]);
        assert!(p.allows("lab-pc:8080"));
        assert!(p.allows("lab-pc.example.org"));
        assert!(p.allows("192.168.1.20:8080"));
        assert!(!p.allows("192.168.1.21:8080"));
        assert!(!p.allows("evil.test:8080"));
        // Bound to every address: any IP literal reached this machine, names still do not pass.
        let any = policy("0.0.0.0:8080", &[]);
        assert!(any.allows("192.168.1.21:8080"));
        assert!(!any.allows("evil.test:8080"));
    }

    #[test]
    fn a_missing_host_is_not_a_browser() {
        let p = policy("127.0.0.1:8080", &[]);
        assert!(p.check(None).is_ok());
        let e = p.check(Some("evil.test:8080")).unwrap_err();
        assert!(matches!(&e, ControlError::Forbidden(m) if m.contains("--allowed-host")));
    }
}
