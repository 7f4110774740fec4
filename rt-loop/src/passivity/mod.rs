//! The time-domain passivity layer (Hannaford and Ryu 2002): an observer of the energy the
//! rendered object has exchanged with the hand ([`observer`]) and an adaptive damper that
//! removes what the object generates ([`controller`]), with their configuration ([`config`]).
//! docs/rt-loop.md, "Passivity layer".

pub mod config;
pub mod controller;
pub mod observer;

pub use config::{PassivityArgs, PassivityConfig, PassivityMode};
pub use controller::{PassivityController, PassivityReport};
pub use observer::EnergyObserver;

impl PassivityController {
    /// The layer a run gets from its configuration: the mode resolved for its board, its
    /// rate's period, and the reproduction's force limit.
    pub fn for_run(cfg: &crate::config::RunConfig) -> Self {
        PassivityController::new(
            &cfg.passivity,
            cfg.passivity.enabled_on(cfg.board),
            1.0 / cfg.rate_hz,
            cfg.reproduction.max_force_n,
        )
    }
}
