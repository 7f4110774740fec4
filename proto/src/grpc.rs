//! The generated `haptics.v1` gRPC messages and clients, and with feature `grpc-server` the
//! servers (tonic + prost, from `proto/haptics/v1/haptics.proto` by `build.rs`). control-plane
//! serves them (`grpc-server`), hapticctl calls them (`grpc`: no server code, no axum, no
//! hyper server); hapticctl links only this, not the control plane.

#![allow(clippy::all, clippy::pedantic, missing_docs)]

tonic::include_proto!("haptics.v1");

/// The encoded descriptor set of `proto/`, served by reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/haptics_descriptor.bin"));

/// The largest answer the server encodes and hapticctl decodes (64 MiB + 64 KiB): one number
/// for both sides, so an answer the server sends is never refused by the client as "decoded
/// message length too large". Answers stay far below it: a model's metadata is capped at load
/// (infer-server's loader limits), so a list of models or a status is small.
pub const MAX_MESSAGE_BYTES: usize = (64 << 20) + (64 << 10);
