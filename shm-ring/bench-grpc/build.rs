//! Compiles `proto/bench.proto` with protox (no system `protoc`) and tonic-prost-build.

fn main() {
    println!("cargo:rerun-if-changed=proto/bench.proto");
    let fds =
        protox::compile(["proto/bench.proto"], ["proto"]).unwrap_or_else(|e| panic!("proto: {e}"));
    tonic_prost_build::configure()
        .build_client(true)
        .build_server(true)
        .compile_fds(fds)
        .unwrap_or_else(|e| panic!("tonic codegen: {e}"));
}
