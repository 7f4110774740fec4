//! The real-time haptics loop (docs/physics.md): board abstraction with a physics-simulated
//! sponge bench and a replay board, the DOB/RFOB force-control loop, the experiments, the nine
//! online features, the lossless recorder and the two clocks.
//!
//! Layout, one folder per component (copper-rs's components around a small core):
//! [`board`] (the trait, `sim`, `replay`, `s826`), [`object`] (the simulated object of any law:
//! its material file, the laws, the oracle), [`control`] (the loop step, [`control::rig`], and
//! what it is made of: the DAC, the pseudo-derivative filters and observers, the bench's
//! friction and its identification), [`experiment`] (the experiments and the simulated hand),
//! [`serving`] (the force-model hook and everything on the served model's path: the
//! shared-memory model, the degradation ladder, the side channel and its recovery, the step
//! sink), [`passivity`], [`record`], [`bringup`] (a real rig's first checks). Beside them:
//! [`features`], [`clock`], [`config`], [`params`], [`run`] (one run), [`daemon`]
//! (`rt-loop serve`), [`stop`], [`percentiles`], [`invalid`], [`lstsq`], [`rng`] (small shared
//! leaves), [`import`] (the `features` subcommand), [`object_force`] (the `object-force`
//! subcommand), [`cli`] and [`app`] (the command line and what it runs; `main` only parses and
//! calls [`app::run`]). See docs/rt-loop.md, "Layout".

pub mod app;
pub mod board;
pub mod bringup;
pub mod cli;
pub mod clock;
pub mod config;
pub mod control;
pub mod daemon;
pub mod experiment;
pub mod features;
pub mod import;
pub mod invalid;
pub mod lstsq;
pub mod object;
pub mod object_force;
pub mod params;
pub mod passivity;
pub mod percentiles;
pub mod record;
pub mod rng;
pub mod run;
pub mod serving;
pub mod stop;
