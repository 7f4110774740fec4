//! Force control: the loop step and what it is made of. [`rig`] runs one step exactly as the
//! thesis code does (read the board, the observers, the experiment's command, the safety
//! checks, the DAC word); [`filters`] are its pseudo-derivatives and DOB/RFOB observers;
//! [`dac`] the amplifier's 16-bit word; [`friction`] the bench's friction model the RFOB
//! subtracts, and [`friction_id`] its identification (`rt-loop identify-friction`). Everything
//! here that runs per step is plain arithmetic on owned state: REAL-TIME PATH, no allocation,
//! no lock, no I/O.

pub mod dac;
pub mod filters;
pub mod friction;
pub mod friction_id;
pub mod rig;
