//! A real gRPC client that is not ours (Python grpcio, reflection only, no .proto file) lists
//! the services and calls status, models, a guarded swap and health.
mod common;

use std::path::PathBuf;

use common::*;
use control_plane::Config;
use control_plane_sim::SimBackend;

fn python() -> PathBuf {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    std::env::var_os("HAPTICS_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join(".venv/bin/python"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpcio_lists_services_by_reflection_and_calls_status() {
    let py = python();
    assert!(
        py.exists(),
        "{} is missing: run scripts/setup.sh (it installs grpcio and grpcio-reflection)",
        py.display()
    );
    let config = Config {
        token: Some("py-token".into()),
        ..test_config()
    };
    let s = start_with(config, SimBackend::with_two_models(RATE_HZ)).await;
    let script =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/py/grpc_reflection_client.py");
    let out = tokio::process::Command::new(&py)
        .arg(&script)
        .arg(s.grpc.to_string())
        .arg("py-token")
        .output()
        .await
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "python failed:\n{stderr}");
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();

    let expected = [
        "grpc.health.v1.Health",
        "grpc.reflection.v1.ServerReflection",
        "grpc.reflection.v1alpha.ServerReflection",
        "haptics.v1.LoopService",
        "haptics.v1.ModelService",
    ];
    for key in ["services_v1", "services_v1alpha"] {
        let got: Vec<&str> = r[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap())
            .collect();
        for svc in expected {
            assert!(got.contains(&svc), "{key}: {svc} missing from {got:?}");
        }
    }
    let st = &r["status"];
    assert_eq!(st["loop_alive"], true);
    assert_eq!(st["rate_hz"], RATE_HZ);
    assert_eq!(st["board"], "sim");
    assert_eq!(st["token_required"], true);
    // uint64 fields are strings in the protobuf JSON mapping.
    assert!(st["step"].as_str().unwrap().parse::<u64>().unwrap() > 0);
    assert_eq!(r["models"]["models"].as_array().unwrap().len(), 2);
    assert_eq!(r["activate_without_token"], "UNAUTHENTICATED");
    assert_eq!(r["status_without_token"], "UNAUTHENTICATED");
    assert_eq!(r["activate"]["model"]["name"], "a.onnx");
    let eff: u64 = r["activate"]["effective_step"]
        .as_str()
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(s.backend.swaps(), vec![eff]);
    assert_eq!(r["bad_name"], "INVALID_ARGUMENT");
    assert_eq!(r["health"], "SERVING");
    s.stop().await;
}
