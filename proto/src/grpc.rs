//! The generated `haptics.v1` gRPC messages and clients, and with feature `grpc-server` the
//! servers (tonic + prost, from `proto/haptics/v1/haptics.proto` by `build.rs`). control-plane
//! serves them (`grpc-server`), hapticctl calls them (`grpc`: no server code, no axum, no
//! hyper server); hapticctl links only this, not the control plane.

#![allow(clippy::all, clippy::pedantic, missing_docs)]

tonic::include_proto!("haptics.v1");

/// The encoded descriptor set of `proto/`, served by reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/haptics_descriptor.bin"));
