//! The real-time haptics loop (docs/physics.md): board abstraction with a physics-simulated
//! sponge bench and a replay board, the DOB/RFOB force-control loop, the experiments, the nine
//! online features, the lossless recorder and the two clocks.
//!
//! Layout: [`board`] (trait + `sim` + `replay`), [`object`] (the simulated object of any law:
//! its material file, the laws, the oracle) and [`hand`] (the simulated world), [`filters`] (pseudo-derivatives, observers), [`rig`] (the step),
//! [`experiment`], [`ladder`], [`passivity`], [`features`], [`model`] (the force-model hook), [`record`],
//! [`clock`], [`config`], [`run`] (one run; its per-step output to a [`sink`]), [`daemon`]
//! (`rt-loop serve`), [`shm_io`]/[`shm_model`]/[`shm_renew`] (the shared-memory side),
//! [`stop`], [`percentiles`], [`invalid`], [`lstsq`] (small shared leaves), [`import`] (the
//! `features` subcommand), [`object_force`] (the `object-force` subcommand), [`cli`] and [`app`] (the command line and what it runs; `main` only
//! parses and calls [`app::run`]). See docs/rt-loop.md, "Layout".

pub mod app;
pub mod board;
pub mod bringup;
pub mod cli;
pub mod clock;
pub mod config;
pub mod dac;
pub mod daemon;
pub mod experiment;
pub mod features;
pub mod filters;
pub mod friction;
pub mod friction_id;
pub mod hand;
pub mod import;
pub mod invalid;
pub mod ladder;
pub mod lstsq;
pub mod model;
pub mod object;
pub mod object_force;
pub mod params;
pub mod passivity;
pub mod percentiles;
pub mod record;
pub mod rig;
pub mod rng;
pub mod run;
pub mod shm_io;
pub mod shm_model;
pub mod shm_renew;
pub mod sink;
pub mod stop;

/// The old paths of the object's modules (before `object/`), kept so code written against them
/// still compiles.
pub mod material {
    pub use crate::object::material::*;
}
pub mod oracle {
    pub use crate::object::oracle::*;
}
pub mod sponge {
    pub use crate::object::foam::*;
}
