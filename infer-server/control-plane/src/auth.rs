//! The bearer token, the same for gRPC (`authorization` metadata) and HTTP (`Authorization`
//! header). With a token, every call that changes something or shows live data or provenance
//! needs it (docs/control-plane.md, "Threat model"); infer-server always has one unless told
//! otherwise, so the control plane is authenticated on loopback too.
use std::sync::Arc;

use crate::error::ControlError;

/// The WebSocket subprotocol the server selects for `/ws/telemetry`.
pub const WS_PROTOCOL: &str = "haptics.v1";
/// Prefix of the subprotocol that carries the token on a WebSocket, hex-encoded (a browser
/// cannot set `Authorization` on a WebSocket, and a subprotocol, unlike a query parameter, is
/// not written into access logs): `haptics-token.<hex of the token's UTF-8 bytes>`.
pub const WS_TOKEN_PREFIX: &str = "haptics-token.";

#[derive(Debug, Clone, Default)]
pub struct Auth {
    token: Option<Arc<str>>,
}

impl Auth {
    pub fn new(token: Option<&str>) -> Self {
        Self {
            token: token.map(Arc::from),
        }
    }

    pub fn required(&self) -> bool {
        self.token.is_some()
    }

    /// Checks an `authorization` value ("Bearer <token>") for a call that changes something or
    /// reads live data. Without a configured token every call passes.
    pub fn check(&self, header: Option<&str>) -> Result<(), ControlError> {
        let Some(expected) = &self.token else {
            return Ok(());
        };
        let Some(header) = header else {
            return Err(ControlError::Unauthenticated(
                "this server needs its token for this call: pass `authorization: Bearer \
                 <token>` (hapticctl reads it from the connection file of the server's owner, \
                 or --token / HAPTICS_TOKEN)"
                    .into(),
            ));
        };
        let given = header
            .strip_prefix("Bearer ")
            .or_else(|| header.strip_prefix("bearer "))
            .map(str::trim)
            .unwrap_or("");
        if constant_time_eq(given.as_bytes(), expected.as_bytes()) {
            Ok(())
        } else {
            Err(ControlError::Unauthenticated(
                "wrong token (expected `authorization: Bearer <token>`)".into(),
            ))
        }
    }

    /// Checks the token of a WebSocket upgrade: `Authorization: Bearer <token>` (clients that
    /// can set headers), or the subprotocol `haptics-token.<hex>` (the page). Without a
    /// configured token every upgrade passes.
    pub fn check_ws(&self, headers: &http::HeaderMap) -> Result<(), ControlError> {
        if !self.required() {
            return Ok(());
        }
        if let Some(auth) = headers
            .get(http::header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
        {
            return self.check(Some(auth));
        }
        let offered = headers
            .get_all(http::header::SEC_WEBSOCKET_PROTOCOL)
            .iter()
            .filter_map(|v| v.to_str().ok())
            .flat_map(|v| v.split(','))
            .map(str::trim)
            .find_map(|p| p.strip_prefix(WS_TOKEN_PREFIX));
        match offered {
            None => self.check(None),
            Some(hex) => {
                let token = decode_hex(hex).unwrap_or_default();
                self.check(Some(&format!("Bearer {token}")))
            }
        }
    }

    pub fn check_grpc<T>(&self, request: &tonic::Request<T>) -> Result<(), tonic::Status> {
        let header = request
            .metadata()
            .get("authorization")
            .and_then(|v| v.to_str().ok());
        self.check(header).map_err(Into::into)
    }
}

/// The longest token accepted: a header line carries it, and a longer one protects nothing more.
pub const MAX_TOKEN_LEN: usize = 256;

/// Checks a configured token: 1 to [`MAX_TOKEN_LEN`] visible ASCII characters (no space, tab,
/// newline or control character). A token with a trailing newline (`$(cat file)` keeps none,
/// `--token "$(echo x; echo)"` does) or of spaces could never be matched: HTTP and gRPC
/// clients trim header values and hapticctl refuses characters a header cannot carry.
pub fn check_token(token: &str) -> Result<(), String> {
    if token.is_empty() {
        return Err("the token is empty: give a non-empty token or none".into());
    }
    if token.len() > MAX_TOKEN_LEN {
        return Err(format!(
            "the token is {} bytes long; at most {MAX_TOKEN_LEN}",
            token.len()
        ));
    }
    if let Some((i, c)) = token.char_indices().find(|(_, c)| !c.is_ascii_graphic()) {
        return Err(format!(
            "the token has {c:?} at byte {i}: only visible ASCII characters (no spaces, tabs, \
             newlines), or no client could ever send it"
        ));
    }
    Ok(())
}

/// `hex` to the string it encodes; None when it is not hex of UTF-8.
fn decode_hex(hex: &str) -> Option<String> {
    let bytes: Option<Vec<u8>> = hex
        .as_bytes()
        .chunks(2)
        .map(|pair| match pair {
            [hi, lo] => u8::from_str_radix(std::str::from_utf8(&[*hi, *lo]).ok()?, 16).ok(),
            _ => None,
        })
        .collect();
    String::from_utf8(bytes?).ok()
}

/// Compares without an early exit, so the time taken does not tell how much of a guess matched.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    let mut diff = a.len() ^ b.len();
    for i in 0..a.len().max(b.len()) {
        let x = a.get(i).copied().unwrap_or(0);
        let y = b.get(i).copied().unwrap_or(0);
        diff |= usize::from(x ^ y);
    }
    diff == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn token_rules() {
        let open = Auth::new(None);
        assert!(open.check(None).is_ok());
        let auth = Auth::new(Some("s3cret"));
        assert!(auth.check(Some("Bearer s3cret")).is_ok());
        for bad in [
            None,
            Some("s3cret"),
            Some("Bearer s3cre"),
            Some("Bearer s3cret2"),
            Some("Bearer "),
        ] {
            assert!(
                matches!(auth.check(bad), Err(ControlError::Unauthenticated(_))),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn configured_tokens_are_checked() {
        assert!(check_token("s3cret").is_ok());
        assert!(check_token(&"a".repeat(MAX_TOKEN_LEN)).is_ok());
        for bad in [
            "", "   ", "s3cret\n", " s3cret", "s3 cret", "s3cret\t", "sécret",
        ] {
            assert!(check_token(bad).is_err(), "{bad:?} accepted");
        }
        assert!(check_token(&"a".repeat(MAX_TOKEN_LEN + 1)).is_err());
    }

    #[test]
    fn websocket_token_by_header_or_subprotocol() {
        let ws = |pairs: &[(&str, &str)]| {
            let mut h = http::HeaderMap::new();
            for (k, v) in pairs {
                h.append(
                    http::HeaderName::from_bytes(k.as_bytes()).unwrap(),
                    v.parse().unwrap(),
                );
            }
            h
        };
        let open = Auth::new(None);
        assert!(open.check_ws(&ws(&[])).is_ok());
        let auth = Auth::new(Some("s3cret"));
        let hex: String = "s3cret".bytes().map(|b| format!("{b:02x}")).collect();
        let good = format!("haptics.v1, haptics-token.{hex}");
        assert!(auth
            .check_ws(&ws(&[("sec-websocket-protocol", &good)]))
            .is_ok());
        assert!(auth
            .check_ws(&ws(&[("authorization", "Bearer s3cret")]))
            .is_ok());
        for bad in [
            vec![],
            vec![("sec-websocket-protocol", "haptics.v1")],
            vec![("sec-websocket-protocol", "haptics-token.7333637265")],
            vec![("sec-websocket-protocol", "haptics-token.zz")],
            vec![("authorization", "Bearer nope")],
        ] {
            assert!(
                matches!(
                    auth.check_ws(&ws(&bad)),
                    Err(ControlError::Unauthenticated(_))
                ),
                "{bad:?}"
            );
        }
    }
}
