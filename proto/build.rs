//! With feature `grpc`: compiles `haptics/v1/haptics.proto` with protox (no system `protoc`)
//! into tonic/prost messages and clients (`haptics_proto::grpc`), and keeps its encoded
//! descriptor set for server reflection (so grpcurl works without the .proto file); with
//! `grpc-server` the servers too (only the control plane serves, so a client such as hapticctl
//! does not compile them). Without `grpc`: nothing.

fn main() {
    #[cfg(feature = "grpc")]
    grpc::compile();
}

#[cfg(feature = "grpc")]
mod grpc {
    use std::path::PathBuf;

    pub fn compile() {
        let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
        let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
        let file = manifest.join("haptics/v1/haptics.proto");
        println!(
            "cargo:rerun-if-changed={}",
            manifest.join("haptics").display()
        );
        let fds = protox::compile([&file], [&manifest]).unwrap_or_else(|e| panic!("proto: {e}"));
        std::fs::write(
            out.join("haptics_descriptor.bin"),
            prost::Message::encode_to_vec(&fds),
        )
        .unwrap();
        tonic_prost_build::configure()
            .build_client(true)
            .build_server(cfg!(feature = "grpc-server"))
            .compile_fds(fds)
            .unwrap_or_else(|e| panic!("tonic codegen: {e}"));
    }
}
