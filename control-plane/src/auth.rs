//! The bearer token of mutating calls, the same for gRPC (`authorization` metadata) and HTTP
//! (`Authorization` header).
use std::sync::Arc;

use crate::error::ControlError;

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

    /// Checks an `authorization` value ("Bearer <token>") for a mutating call. Without a
    /// configured token every call passes.
    pub fn check(&self, header: Option<&str>) -> Result<(), ControlError> {
        let Some(expected) = &self.token else {
            return Ok(());
        };
        let Some(header) = header else {
            return Err(ControlError::Unauthenticated(
                "this call changes the server and needs a token: pass `authorization: Bearer \
                 <token>` (hapticctl --token or HAPTICS_TOKEN)"
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

    pub fn check_grpc<T>(&self, request: &tonic::Request<T>) -> Result<(), tonic::Status> {
        let header = request
            .metadata()
            .get("authorization")
            .and_then(|v| v.to_str().ok());
        self.check(header).map_err(Into::into)
    }
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
}
