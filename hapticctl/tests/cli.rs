//! hapticctl against the real control plane over a simulated backend.
use std::sync::Arc;

use control_plane::{Config, Shutdown};
use control_plane_sim::{model_file, SimBackend};

struct Server {
    addr: String,
    shutdown: Shutdown,
    backend: Arc<SimBackend>,
}

impl Drop for Server {
    fn drop(&mut self) {
        self.shutdown.trigger();
    }
}

async fn server(token: Option<&str>) -> Server {
    let config = Config {
        grpc_addr: "127.0.0.1:0".parse().unwrap(),
        http_addr: "127.0.0.1:0".parse().unwrap(),
        token: token.map(String::from),
        max_upload_bytes: 1 << 16,
        ..Config::default()
    };
    let backend = SimBackend::with_two_models(10_000.0);
    let shutdown = Shutdown::new();
    let bound = control_plane::bind(config, backend.clone(), shutdown.clone())
        .await
        .unwrap();
    let addr = bound.grpc_addr().to_string();
    tokio::spawn(bound.run());
    Server {
        addr,
        shutdown,
        backend,
    }
}

struct Out {
    code: i32,
    stdout: String,
    stderr: String,
}

async fn ctl(s: &Server, args: &[&str]) -> Out {
    ctl_env(&s.addr, args, &[]).await
}

async fn ctl_env(addr: &str, args: &[&str], env: &[(&str, &str)]) -> Out {
    let mut with_addr = vec!["--addr", addr];
    with_addr.extend_from_slice(args);
    // No connection file of a real server on this machine gets in (an empty runtime directory).
    let empty = tempfile::tempdir().unwrap();
    let mut env: Vec<(&str, &str)> = env.to_vec();
    let xdg = empty.path().to_str().unwrap().to_string();
    if !env.iter().any(|(k, _)| *k == "XDG_RUNTIME_DIR") {
        env.push(("XDG_RUNTIME_DIR", &xdg));
    }
    ctl_raw(&with_addr, &env).await
}

/// hapticctl with exactly these arguments and environment (no --addr added).
async fn ctl_raw(args: &[&str], env: &[(&str, &str)]) -> Out {
    let mut cmd = tokio::process::Command::new(env!("CARGO_BIN_EXE_hapticctl"));
    cmd.args(args)
        .env_remove("HAPTICS_TOKEN")
        .env_remove("HAPTICS_ADDR")
        .env_remove("HAPTICS_INSTANCE");
    for (k, v) in env {
        cmd.env(k, v);
    }
    let o = cmd.output().await.unwrap();
    Out {
        code: o.status.code().unwrap_or(-1),
        stdout: String::from_utf8(o.stdout).unwrap(),
        stderr: String::from_utf8(o.stderr).unwrap(),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn models_swap_unload_and_active() {
    let s = server(None).await;
    let o = ctl(&s, &["models"]).await;
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(o.stdout.starts_with("NAME"), "{}", o.stdout);
    assert!(
        o.stdout
            .lines()
            .any(|l| l.starts_with("a.onnx") && l.contains("available")),
        "{}",
        o.stdout
    );

    let o = ctl(&s, &["swap", "b.onnx"]).await;
    assert_eq!(o.code, 0, "{}", o.stderr);
    let step = s.backend.swaps()[0];
    assert_eq!(
        o.stdout.trim(),
        format!(
            "b.onnx is active from feature message {step} (the segment's count since the loop \
             started serving; status's step counts the current run)"
        )
    );

    let o = ctl(&s, &["--json", "models"]).await;
    let list: serde_json::Value = serde_json::from_str(&o.stdout).unwrap();
    assert_eq!(list[1]["name"], "b.onnx");
    assert_eq!(list[1]["state"], "active");
    assert_eq!(list[1]["active_since_step"], step);

    let o = ctl(&s, &["--json", "swap", "a.onnx"]).await;
    let r: serde_json::Value = serde_json::from_str(&o.stdout).unwrap();
    assert_eq!(r["effective_step"], s.backend.swaps()[1]);
    assert_eq!(r["model"]["name"], "a.onnx");

    let o = ctl(&s, &["active"]).await;
    assert!(o.stdout.starts_with("a.onnx (active"), "{}", o.stdout);
    let o = ctl(&s, &["unload", "b.onnx"]).await;
    assert_eq!(
        (o.code, o.stdout.trim()),
        (0, "unloaded b.onnx"),
        "{}",
        o.stderr
    );
    let o = ctl(&s, &["unload", "a.onnx"]).await;
    assert_eq!(o.code, 1);
    assert!(o.stderr.contains("active model"), "{}", o.stderr);
}

/// A swap that succeeded and made `name` the active model.
fn swapped_to(o: &Out, name: &str) {
    assert_eq!(o.code, 0, "{}", o.stderr);
    let said = format!("{name} is active from feature message");
    assert!(o.stdout.starts_with(&said), "{}", o.stdout);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uploads_from_local_files_and_clear_refusals() {
    let s = server(None).await;
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("mine.onnx");
    std::fs::write(&good, model_file(&["position_x"], 1.5)).unwrap();
    let bad = dir.path().join("corrupt.onnx");
    std::fs::write(&bad, b"\x00\x01 not a model").unwrap();
    let wrong = dir.path().join("wrong.onnx");
    std::fs::write(&wrong, model_file(&["jerk"], 1.0)).unwrap();
    let big = dir.path().join("big.onnx");
    std::fs::write(&big, vec![b' '; (1 << 16) + 1]).unwrap();

    let o = ctl(
        &s,
        &["load", "--file", good.to_str().unwrap(), "--as", "up.onnx"],
    )
    .await;
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(
        o.stdout
            .starts_with("loaded up.onnx (loaded, stateless, features: position_x"),
        "{}",
        o.stdout
    );

    // A path swaps by uploading first.
    swapped_to(
        &ctl(&s, &["swap", good.to_str().unwrap()]).await,
        "mine.onnx",
    );

    for (file, why) in [
        (&bad, "refused: not a model file"),
        (&wrong, "not possible now: the model needs feature \"jerk\""),
    ] {
        let o = ctl(&s, &["swap", file.to_str().unwrap()]).await;
        assert_eq!(o.code, 1, "{}", o.stdout);
        assert!(o.stderr.contains(why), "{}", o.stderr);
        let o = ctl(&s, &["--json", "active"]).await;
        assert!(
            o.stdout.contains("\"name\":\"mine.onnx\""),
            "still serving: {}",
            o.stdout
        );
    }
    // ... under a name of its own with --as; --as names an upload, so a bare name is refused.
    let args = ["swap", good.to_str().unwrap(), "--as", "mine_v2.onnx"];
    swapped_to(&ctl(&s, &args).await, "mine_v2.onnx");
    let o = ctl(&s, &["swap", "a.onnx", "--as", "x.onnx"]).await;
    assert_eq!(o.code, 2, "{}", o.stdout);
    assert!(o.stderr.contains("is not a local file"), "{}", o.stderr);

    let o = ctl(&s, &["load", "--file", big.to_str().unwrap()]).await;
    assert_eq!(o.code, 1);
    assert!(
        o.stderr
            .contains("over the server's upload limit of 65536 bytes"),
        "{}",
        o.stderr
    );
    let o = ctl(&s, &["load", "nope.onnx"]).await;
    assert_eq!(o.code, 1);
    assert!(o.stderr.contains("not found"), "{}", o.stderr);
    let o = ctl(&s, &["load", "--file", "/does/not/exist.onnx"]).await;
    assert_eq!(o.code, 2);
    assert!(
        o.stderr.contains("cannot read /does/not/exist.onnx"),
        "{}",
        o.stderr
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn token_from_flag_or_environment() {
    let s = server(Some("t0k")).await;
    let o = ctl(&s, &["swap", "a.onnx"]).await;
    assert_eq!(o.code, 1);
    assert!(
        o.stderr.contains("--token") && o.stderr.contains("HAPTICS_TOKEN"),
        "{}",
        o.stderr
    );
    let o = ctl(&s, &["--token", "bad", "swap", "a.onnx"]).await;
    assert!(o.stderr.contains("wrong token"), "{}", o.stderr);
    assert!(s.backend.swaps().is_empty());
    let o = ctl(&s, &["status"]).await;
    assert_eq!(o.code, 1, "reading needs the token too: {}", o.stderr);
    assert!(
        o.stderr.starts_with("hapticctl: GetStatus failed:"),
        "{}",
        o.stderr
    );
    let o = ctl(&s, &["--token", "t0k", "swap", "a.onnx"]).await;
    assert_eq!(o.code, 0, "{}", o.stderr);
    let o = ctl_env(&s.addr, &["swap", "b.onnx"], &[("HAPTICS_TOKEN", "t0k")]).await;
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert_eq!(s.backend.swaps().len(), 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_experiments_and_telemetry() {
    let s = server(None).await;
    let o = ctl(&s, &["status"]).await;
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(
        o.stdout
            .contains("loop:        running, realtime clock, sim board, 10000.0 Hz"),
        "{}",
        o.stdout
    );
    assert!(o.stdout.contains("model:       none"), "{}", o.stdout);

    let o = ctl(
        &s,
        &[
            "experiment",
            "start",
            "abstraction",
            "--ramp-rate",
            "2.1",
            "--cycles",
            "10",
        ],
    )
    .await;
    assert_eq!(
        (o.code, o.stdout.trim()),
        (0, "started abstraction"),
        "{}",
        o.stderr
    );
    let req = s.backend.last_experiment().unwrap();
    assert_eq!((req.ramp_rate, req.cycles), (Some(2.1), Some(10)));
    let o = ctl(&s, &["--json", "status"]).await;
    let st: serde_json::Value = serde_json::from_str(&o.stdout).unwrap();
    assert_eq!(st["loop"]["mode"], "abstraction");
    assert_eq!(st["loop"]["experiment"]["running"], true);
    let o = ctl(&s, &["experiment", "start", "juggling"]).await;
    assert_eq!(o.code, 1);
    assert!(o.stderr.contains("unknown experiment kind"), "{}", o.stderr);
    let o = ctl(&s, &["experiment", "stop"]).await;
    assert_eq!((o.code, o.stdout.trim()), (0, "stopped"));

    let o = ctl(
        &s,
        &[
            "--json",
            "status",
            "--watch",
            "--interval",
            "0.05",
            "--count",
            "3",
        ],
    )
    .await;
    let steps: Vec<u64> = o
        .stdout
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["loop"]["step"]
                .as_u64()
                .unwrap()
        })
        .collect();
    assert_eq!(steps.len(), 3);
    assert!(steps[2] > steps[0], "{steps:?}");

    let o = ctl(
        &s,
        &["--json", "telemetry", "--decimation", "100", "--count", "5"],
    )
    .await;
    assert_eq!(o.code, 0, "{}", o.stderr);
    let samples: Vec<serde_json::Value> = o
        .stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(samples.len(), 5);
    for w in samples.windows(2) {
        assert_eq!(w[0]["steps"], 100);
        assert_eq!(
            w[1]["step"].as_u64().unwrap(),
            w[0]["step"].as_u64().unwrap() + 100
        );
        assert!(w[0]["f_pred"].is_null(), "NaN without a model");
    }
    let o = ctl(&s, &["telemetry", "--decimation", "100", "--count", "2"]).await;
    assert_eq!(o.stdout.lines().count(), 3, "{}", o.stdout);
    assert!(o.stdout.starts_with("      step"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_server_says_so() {
    // A port free a moment ago on 127.0.0.1 can be taken by a server of a test running beside
    // this one (that made this test fail once in CI); no test here listens on 127.0.0.77, so a
    // port freed there stays refused.
    let free = std::net::TcpListener::bind("127.0.0.77:0").unwrap();
    let addr = free.local_addr().unwrap().to_string();
    drop(free);
    let o = ctl_env(&addr, &["status"], &[]).await;
    assert_eq!(o.code, 3);
    assert!(
        o.stderr.contains("Is infer-server running?"),
        "{}",
        o.stderr
    );
    assert!(
        o.stderr.to_lowercase().contains("connection refused"),
        "{}",
        o.stderr
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_owner_needs_no_token_the_connection_file_has_it() {
    let s = server(Some("f11e-token")).await;
    let xdg = tempfile::tempdir().unwrap();
    let dir = xdg.path().join("haptics");
    std::fs::create_dir(&dir).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700)).unwrap();
    let grpc = format!("http://{}", s.addr);
    let file = format!(
        "{{\"instance\": \"lab\", \"pid\": 1, \"grpc\": \"{grpc}\", \"http\": \"http://127.0.0.1:1\", \
         \"token\": \"f11e-token\", \"page\": \"http://127.0.0.1:1/#token=f11e-token\"}}"
    );
    std::fs::write(dir.join("lab.json"), file).unwrap();
    let xdg_s = xdg.path().to_str().unwrap();
    let env = [("XDG_RUNTIME_DIR", xdg_s), ("HAPTICS_INSTANCE", "lab")];
    // Address and token both from the file.
    let o = ctl_raw(&["swap", "a.onnx"], &env).await;
    assert_eq!(o.code, 0, "{}", o.stderr);
    let o = ctl_raw(
        &["--instance", "lab", "status"],
        &[("XDG_RUNTIME_DIR", xdg_s)],
    )
    .await;
    assert_eq!(o.code, 0, "{}", o.stderr);
    // The file's token goes only to the file's address: another address gets none.
    let o = ctl_raw(&["--addr", "127.0.0.1:1", "status"], &env).await;
    assert_eq!(o.code, 3, "{}", o.stderr);
    let o = ctl_raw(&["--addr", &s.addr, "status"], &env).await;
    assert_eq!(
        o.code, 0,
        "the same address written without http://: {}",
        o.stderr
    );
    // An explicit token wins over the file's.
    let o = ctl_raw(&["--token", "wrong-token", "status"], &env).await;
    assert_eq!(o.code, 1, "{}", o.stderr);
    // A directory others may enter is not trusted: said, and ignored.
    std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).unwrap();
    let o = ctl_raw(&["status"], &env).await;
    assert!(
        o.stderr.contains("ignoring the connection file"),
        "{}",
        o.stderr
    );
    assert_ne!(o.code, 0, "{}", o.stderr);
    std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700)).unwrap();
    // No file at all (an older server, or none): the default address, no token, no error.
    let o = ctl_raw(
        &["--addr", &s.addr, "--instance", "nothing-here", "status"],
        &[("XDG_RUNTIME_DIR", xdg_s)],
    )
    .await;
    assert_eq!(
        o.code, 1,
        "refused for want of a token, not a file error: {}",
        o.stderr
    );
    assert!(!o.stderr.contains("connection file:"), "{}", o.stderr);
    assert_eq!(s.backend.swaps().len(), 1);
}
