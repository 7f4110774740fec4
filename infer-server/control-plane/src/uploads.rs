//! The cap on model uploads held in memory while they are received: every upload in progress
//! (gRPC `LoadModel` with bytes, HTTP `POST /api/models/{name}/load` with a body) reserves the
//! per-upload limit before its body is read and gives it back when the call ends, so many
//! concurrent uploads cannot make the server hold more than `max_uploads_in_flight_bytes`.
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use crate::error::ControlError;

#[derive(Debug, Clone)]
pub struct UploadBudget {
    in_use: Arc<AtomicUsize>,
    cap: usize,
}

/// A reservation; given back on drop.
#[derive(Debug)]
pub struct Reservation {
    in_use: Arc<AtomicUsize>,
    bytes: usize,
}

impl Drop for Reservation {
    fn drop(&mut self) {
        self.in_use.fetch_sub(self.bytes, Ordering::AcqRel);
    }
}

impl UploadBudget {
    pub fn new(cap: usize) -> Self {
        Self {
            in_use: Arc::new(AtomicUsize::new(0)),
            cap,
        }
    }

    /// Bytes reserved right now.
    pub fn in_use(&self) -> usize {
        self.in_use.load(Ordering::Acquire)
    }

    /// Reserves `bytes`, or refuses (RESOURCE_EXHAUSTED / 413) when the cap would be passed.
    pub fn reserve(&self, bytes: usize) -> Result<Reservation, ControlError> {
        let mut current = self.in_use.load(Ordering::Acquire);
        loop {
            let next = current.checked_add(bytes).filter(|&n| n <= self.cap);
            let Some(next) = next else {
                return Err(ControlError::TooLarge(format!(
                    "too many model uploads at once: {current} of the server's {} bytes for \
                     uploads in progress are taken; try again when the others have finished",
                    self.cap
                )));
            };
            match self.in_use.compare_exchange_weak(
                current,
                next,
                Ordering::AcqRel,
                Ordering::Acquire,
            ) {
                Ok(_) => {
                    return Ok(Reservation {
                        in_use: Arc::clone(&self.in_use),
                        bytes,
                    })
                }
                Err(seen) => current = seen,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reservations_are_capped_and_given_back() {
        let b = UploadBudget::new(100);
        let r1 = b.reserve(60).unwrap();
        assert!(matches!(b.reserve(41), Err(ControlError::TooLarge(_))));
        let r2 = b.reserve(40).unwrap();
        assert_eq!(b.in_use(), 100);
        drop(r1);
        assert_eq!(b.in_use(), 40);
        assert!(b.reserve(usize::MAX).is_err());
        drop(r2);
        assert_eq!(b.in_use(), 0);
    }
}
