//! Where the view listens: loopback unless the user says otherwise.
//!
//! The page shows a sensor's live data and the machine's device health;
//! serving it to the network is a choice, so an address other than
//! loopback is refused without `--allow-remote`.

use std::net::{IpAddr, Ipv4Addr, SocketAddr, TcpListener};

/// The view's port when none is given.
pub const DEFAULT_PORT: u16 = 8093;

/// Why the view cannot listen where asked.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum AddressError {
    #[error("{0:?} is not an address to serve the view on: give PORT, ADDR:PORT or [IPv6]:PORT (e.g. 8093, 127.0.0.1:8093)")]
    Unparsable(String),
    #[error("refusing to serve the view on {0}: it is not a loopback address, so anyone who can reach this machine could watch; add --allow-remote to serve it there anyway, or use 127.0.0.1")]
    NotLoopback(SocketAddr),
    #[error("port {port} on {ip} is in use (another view or program listens there): choose another port, or port 0 for any free one")]
    InUse { ip: IpAddr, port: u16 },
    #[error("cannot listen on {addr}: {reason}")]
    Other { addr: SocketAddr, reason: String },
}

/// `PORT`, `ADDR:PORT` or `[IPv6]:PORT`; a bare port is on 127.0.0.1.
pub fn parse(text: &str) -> Result<SocketAddr, AddressError> {
    let text = text.trim();
    if let Ok(port) = text.parse::<u16>() {
        return Ok(SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), port));
    }
    if let Some(port) = text.strip_prefix("localhost:") {
        if let Ok(port) = port.parse::<u16>() {
            return Ok(SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), port));
        }
    }
    text.parse()
        .map_err(|_| AddressError::Unparsable(text.to_string()))
}

/// Refuses a non-loopback address unless `allow_remote`.
pub fn check(addr: SocketAddr, allow_remote: bool) -> Result<(), AddressError> {
    if addr.ip().is_loopback() || allow_remote {
        Ok(())
    } else {
        Err(AddressError::NotLoopback(addr))
    }
}

/// Checks and binds `addr`, saying plainly when the port is taken.
pub fn bind(addr: SocketAddr, allow_remote: bool) -> Result<TcpListener, AddressError> {
    check(addr, allow_remote)?;
    TcpListener::bind(addr).map_err(|e| match e.kind() {
        std::io::ErrorKind::AddrInUse => AddressError::InUse {
            ip: addr.ip(),
            port: addr.port(),
        },
        _ => AddressError::Other {
            addr,
            reason: e.to_string(),
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bare_ports_are_loopback() {
        assert_eq!(parse("8093").unwrap(), "127.0.0.1:8093".parse().unwrap());
        assert_eq!(
            parse("localhost:9000").unwrap(),
            "127.0.0.1:9000".parse().unwrap()
        );
        assert_eq!(parse("[::1]:80").unwrap(), "[::1]:80".parse().unwrap());
        assert!(matches!(parse("nowhere"), Err(AddressError::Unparsable(_))));
        assert!(matches!(parse("1.2.3.4"), Err(AddressError::Unparsable(_))));
    }

    #[test]
    fn other_addresses_need_the_flag() {
        let any: SocketAddr = "0.0.0.0:8093".parse().unwrap();
        let error = check(any, false).unwrap_err();
        assert_eq!(error, AddressError::NotLoopback(any));
        assert!(error.to_string().contains("--allow-remote"), "{error}");
        assert!(check(any, true).is_ok());
        assert!(check("127.0.0.2:1".parse().unwrap(), false).is_ok());
        assert!(check("[::1]:1".parse().unwrap(), false).is_ok());
        // Refused before any socket is opened.
        assert!(matches!(
            bind("0.0.0.0:0".parse().unwrap(), false),
            Err(AddressError::NotLoopback(_))
        ));
    }

    #[test]
    fn a_taken_port_says_so() {
        let first = bind("127.0.0.1:0".parse().unwrap(), false).unwrap();
        let addr = first.local_addr().unwrap();
        let error = bind(addr, false).unwrap_err();
        assert_eq!(
            error,
            AddressError::InUse {
                ip: addr.ip(),
                port: addr.port()
            }
        );
        assert!(error.to_string().contains("in use"), "{error}");
    }
}
