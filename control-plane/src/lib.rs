//! The control plane: gRPC and HTTP services over a `Backend` that infer-server implements.
