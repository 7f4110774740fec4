//! Generated client and server for the benchmark's `shmbench.Predictor` service.
#![allow(clippy::all, missing_docs)]

tonic::include_proto!("shmbench");
