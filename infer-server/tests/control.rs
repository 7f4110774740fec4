//! `infer-server serve` as a real process, driven over real gRPC (the generated client of
//! `control_plane::pb`) while this test plays rt-loop on a real shared-memory segment: it
//! creates the segment, sends features and reads forces on its own thread, writes telemetry
//! rows, heartbeats, and reads the command mailbox.

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use control_plane::pb;
use control_plane::pb::loop_service_client::LoopServiceClient;
use control_plane::pb::model_service_client::ModelServiceClient;
use haptics_proto::experiment_args::ExperimentArgs;
use haptics_proto::{
    Command as LoopCommand, FeatureMsg, LoopSide, Segment, TelemetryRow, MAX_FEATURES,
};
use shm_ring::{Config, SegmentName, WaitStrategy};
use tonic::transport::Channel;
use tonic::Code;

/// The loop's schema in these tests: a subset of the nine, so a model that wants
/// `deformation` does not fit it.
const SCHEMA: [&str; 4] = ["position_x", "velocity", "acceleration", "f_previous_x"];

fn segment_name(tag: &str) -> SegmentName {
    SegmentName::new(&format!("/infer-server-ctl-{tag}-{}", std::process::id())).unwrap()
}

fn loop_config() -> Config {
    Config {
        feature_names: SCHEMA.iter().map(|s| s.to_string()).collect(),
        ..haptics_proto::layout::config()
    }
}

/// A model directory with copies of the named fixtures.
fn models_dir(tag: &str, fixtures: &Path, names: &[&str]) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("ctl-models-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    for n in names {
        std::fs::copy(
            fixtures.join(format!("{n}.onnx")),
            dir.join(format!("{n}.onnx")),
        )
        .unwrap();
    }
    dir
}

/// The token these tests' servers get through HAPTICS_TOKEN (infer-server requires one on
/// every call, on loopback too), unless a test gives its own with `--token`.
const CTL_TOKEN: &str = "ctl-test-token-8d2e";

/// A client whose calls carry `token` unless the call set its own `authorization`.
type Authed = tonic::service::interceptor::InterceptedService<Channel, AddToken>;

#[derive(Clone)]
struct AddToken(Option<String>);

impl tonic::service::Interceptor for AddToken {
    fn call(&mut self, mut r: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(t) = &self.0 {
            if !r.metadata().contains_key("authorization") {
                let v = format!("Bearer {t}").parse().expect("ASCII token");
                r.metadata_mut().insert("authorization", v);
            }
        }
        Ok(r)
    }
}

struct ServerProcess {
    child: Child,
    grpc: String,
    http: String,
    stderr: PathBuf,
    /// The token the clients send by default: CTL_TOKEN, or none when the test chose one.
    token: Option<String>,
}

impl ServerProcess {
    fn start(tag: &str, dir: &Path, segment: &SegmentName, extra: &[&str]) -> Self {
        let stderr = Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("ctl-{tag}-{}.stderr", std::process::id()));
        let mut child = Command::new(env!("CARGO_BIN_EXE_infer-server"))
            .args(["serve", "--wait", "park", "--stats-every", "0"])
            .args(["--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0"])
            .arg("--models")
            .arg(dir)
            .args(["--segment", segment.as_str()])
            .args(extra)
            .env("HAPTICS_TOKEN", CTL_TOKEN)
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&stderr).unwrap())
            .spawn()
            .unwrap();
        // "infer-server: gRPC ADDR HTTP http://ADDR segment ..." on stdout, once bound.
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let words: Vec<&str> = line.split_whitespace().collect();
        let at = |key: &str| {
            let i = words
                .iter()
                .position(|w| *w == key)
                .unwrap_or_else(|| panic!("no {key} in {line:?}: {}", read(&stderr)));
            words[i + 1].to_string()
        };
        let grpc = format!("http://{}", at("gRPC"));
        let http = at("HTTP").trim_start_matches("http://").to_string();
        let token = (!extra.contains(&"--token")).then(|| CTL_TOKEN.to_string());
        Self {
            child,
            grpc,
            http,
            stderr,
            token,
        }
    }

    fn stderr(&self) -> String {
        read(&self.stderr)
    }

    async fn channel(&self) -> Channel {
        tonic::transport::Endpoint::from_shared(self.grpc.clone())
            .unwrap()
            .connect()
            .await
            .unwrap()
    }

    async fn models(&self) -> ModelServiceClient<Authed> {
        self.models_with(self.token.clone()).await
    }

    async fn models_with(&self, token: Option<String>) -> ModelServiceClient<Authed> {
        ModelServiceClient::with_interceptor(self.channel().await, AddToken(token))
    }

    async fn loop_client(&self) -> LoopServiceClient<Authed> {
        self.loop_client_with(self.token.clone()).await
    }

    async fn loop_client_with(&self, token: Option<String>) -> LoopServiceClient<Authed> {
        LoopServiceClient::with_interceptor(self.channel().await, AddToken(token))
    }

    /// SIGTERM, then the exit status and how long the exit took.
    fn terminate(&mut self) -> (std::process::ExitStatus, Duration) {
        let t0 = Instant::now();
        // SAFETY: a signal to our own child.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                return (s, t0.elapsed());
            }
            if t0.elapsed() > Duration::from_secs(10) {
                self.child.kill().unwrap();
                panic!("infer-server did not exit after SIGTERM: {}", self.stderr());
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for ServerProcess {
    /// SIGINT first, as a user stops the server: its clean exit removes the connection file
    /// (a SIGKILL left one per test in the runtime directory); SIGKILL if it has not exited
    /// within 5 s.
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_some() {
            return;
        }
        // SAFETY: kill(2) on our own child's pid, which wait() has not reaped yet.
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGINT) };
        let end = Instant::now() + Duration::from_secs(5);
        while Instant::now() < end {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_default()
}

/// The features this test's loop sends at step `seq`, in SCHEMA order.
fn features_at(seq: u64) -> [f64; 4] {
    let s = seq as f64;
    [
        0.001 * (seq % 100) as f64,
        (s * 0.01).cos(),
        (s * 0.02).sin(),
        3.0 * (s * 0.003).sin(),
    ]
}

/// A fixture model's force as a function of the features (SCHEMA order).
/// A loop side on a new segment `segment` that has published `status` (the rate and feature
/// filters infer-server checks a model against when it activates it).
fn loop_publishing(segment: &SegmentName, status: &haptics_proto::LoopStatus) -> LoopSide {
    use haptics_proto::LoopStatusLink;
    let lp = Segment::create(segment, &loop_config())
        .unwrap()
        .loop_side()
        .unwrap();
    lp.link.publish_loop_status(status);
    lp
}

/// Waits (at most 20 s) until the server has an active model.
async fn wait_active(c: &mut ModelServiceClient<Authed>, server: &ServerProcess) {
    let end = Instant::now() + Duration::from_secs(20);
    while c
        .get_active_model(pb::GetActiveModelRequest {})
        .await
        .is_err()
    {
        assert!(Instant::now() < end, "no active model: {}", server.stderr());
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

type Formula = fn(&[f64; 4]) -> f64;

/// tests/fixtures/make_models.py: linear = 2 velocity - 3 position_x + 0.5.
fn linear(f: &[f64; 4]) -> f64 {
    2.0 * f[1] - 3.0 * f[0] + 0.5
}

/// tests/fixtures/make_models.py: tree0(position_x, f_previous_x) + tree1(f_previous_x) + 0.25.
fn tree(f: &[f64; 4]) -> f64 {
    let (x, fp) = (f[0] as f32, f[3] as f32);
    let t0 = if x <= 0.5 {
        1.0
    } else if fp <= 2.0 {
        2.0
    } else {
        3.0
    };
    let t1 = if fp <= -1.0 { 10.0 } else { 20.0 };
    t0 + t1 + 0.25
}

#[derive(Debug, Clone, Copy)]
struct Answer {
    seq: u64,
    force: f64,
    model_id: u32,
    flags: u32,
}

/// This test's rt-loop: one step every ~0.5 ms in lockstep (each step waits for its answer,
/// parking), heartbeat per step. Every answer is logged; a wrong or missing answer panics
/// the thread, which `stop` reports.
struct StepLoop {
    stop: Arc<AtomicBool>,
    log: Arc<Mutex<Vec<Answer>>>,
    thread: Option<JoinHandle<LoopSide>>,
}

impl StepLoop {
    fn start(lp: LoopSide) -> Self {
        Self::start_with(lp, vec![0, 1, 2, 3])
    }

    /// `order[i]`: which of SCHEMA's features the loop's slot i carries (its own schema).
    fn start_with(mut lp: LoopSide, order: Vec<usize>) -> Self {
        lp.forces_rx.set_wait_strategy(WaitStrategy::Park);
        let stop = Arc::new(AtomicBool::new(false));
        let log = Arc::new(Mutex::new(Vec::new()));
        let (s, l) = (Arc::clone(&stop), Arc::clone(&log));
        let thread = std::thread::spawn(move || {
            let end = Instant::now() + Duration::from_secs(20);
            while !lp.peer_alive() {
                assert!(Instant::now() < end, "the server did not attach");
                lp.heartbeat();
                std::thread::sleep(Duration::from_millis(5));
            }
            let mut seq = 0u64;
            while !s.load(Ordering::Relaxed) {
                seq += 1;
                let f = features_at(seq);
                let mut values = [0.0; MAX_FEATURES];
                for (slot, &i) in order.iter().enumerate() {
                    values[slot] = f[i];
                }
                let msg = FeatureMsg {
                    seq,
                    timestamp_ns: seq * 100_000,
                    run_id: 1,
                    flags: u32::from(seq == 1),
                    len: order.len() as u8,
                    values,
                };
                lp.features_tx.try_send(msg).unwrap();
                let a = match lp.forces_rx.recv_timeout(Duration::from_secs(10)) {
                    Ok(a) => a,
                    // The server exited (the shutdown test): the loop would go on on its
                    // fallback; this one stops.
                    Err(shm_ring::RecvError::PeerGone) => break,
                    Err(e) => panic!("step {seq}: {e}"),
                };
                assert_eq!(a.seq, seq, "answers come in order, one per step");
                l.lock().unwrap().push(Answer {
                    seq,
                    force: a.force,
                    model_id: a.model_id,
                    flags: a.flags,
                });
                lp.heartbeat();
                std::thread::sleep(Duration::from_micros(500));
            }
            lp
        });
        Self {
            stop,
            log,
            thread: Some(thread),
        }
    }

    fn answers(&self) -> Vec<Answer> {
        self.log.lock().unwrap().clone()
    }

    fn last_seq(&self) -> u64 {
        self.log.lock().unwrap().last().map_or(0, |a| a.seq)
    }

    /// Waits until the loop has answered step `seq`.
    fn wait_for(&self, seq: u64) {
        let end = Instant::now() + Duration::from_secs(10);
        while self.last_seq() < seq {
            assert!(
                !self.thread.as_ref().unwrap().is_finished(),
                "the loop thread ended"
            );
            assert!(Instant::now() < end, "the loop did not reach step {seq}");
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    fn stop_and_answers(self) -> Vec<Answer> {
        let log = Arc::clone(&self.log);
        drop(self.stop());
        let answers = log.lock().unwrap().clone();
        answers
    }

    fn stop(mut self) -> LoopSide {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().unwrap().join() {
            Ok(lp) => lp,
            Err(p) => std::panic::resume_unwind(p),
        }
    }
}

fn model<'a>(list: &'a [pb::ModelInfo], name: &str) -> &'a pb::ModelInfo {
    list.iter()
        .find(|m| m.name == name)
        .unwrap_or_else(|| panic!("{name} not listed: {list:?}"))
}

async fn list(c: &mut ModelServiceClient<Authed>) -> Vec<pb::ModelInfo> {
    c.list_models(pb::ListModelsRequest {})
        .await
        .unwrap()
        .into_inner()
        .models
}

async fn load(
    c: &mut ModelServiceClient<Authed>,
    name: &str,
) -> Result<pb::ModelInfo, tonic::Status> {
    c.load_model(pb::LoadModelRequest {
        name: name.into(),
        onnx: Vec::new(),
    })
    .await
    .map(|r| r.into_inner().model.unwrap())
}

async fn activate(
    c: &mut ModelServiceClient<Authed>,
    name: &str,
    load_if_needed: bool,
) -> Result<pb::ActivateModelResponse, tonic::Status> {
    c.activate_model(pb::ActivateModelRequest {
        name: name.into(),
        load_if_needed,
    })
    .await
    .map(|r| r.into_inner())
}

/// Every answer from `from` on (until `until`) came from `model_id` with `expected`'s force.
fn check_model_answers(
    answers: &[Answer],
    from: u64,
    until: u64,
    model_id: u32,
    expected: Formula,
) {
    let mut n = 0;
    for a in answers.iter().filter(|a| a.seq >= from && a.seq < until) {
        assert_eq!(a.flags, 0, "step {}: {a:?}", a.seq);
        assert_eq!(a.model_id, model_id, "step {}: {a:?}", a.seq);
        let want = expected(&features_at(a.seq));
        assert!(
            (a.force - want).abs() < 1e-4,
            "step {}: force {} but the model gives {want}",
            a.seq,
            a.force
        );
        n += 1;
    }
    assert!(n > 0, "no answers in [{from}, {until})");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn models_load_activate_swap_and_refusals_over_grpc() {
    let Some(fixtures) = common::fixtures() else {
        return;
    };
    let names = [
        "linear",
        "tree",
        "corrupt",
        "wrong_input",
        "nan_output",
        "needs_deformation",
        "linear_reference",
    ];
    let dir = models_dir("swap", fixtures, &names);
    let segment = segment_name("swap");
    let lp = Segment::create(&segment, &loop_config())
        .unwrap()
        .loop_side()
        .unwrap();
    let server = ServerProcess::start("swap", &dir, &segment, &["--model", "linear.onnx"]);
    let stepper = StepLoop::start(lp);
    let mut c = server.models().await;

    // --model: linear is activated once the loop attached.
    let end = Instant::now() + Duration::from_secs(20);
    let linear_id = loop {
        let active = c.get_active_model(pb::GetActiveModelRequest {}).await;
        if let Ok(m) = active {
            let m = m.into_inner();
            assert_eq!(m.name, "linear.onnx");
            break m.model_id;
        }
        assert!(Instant::now() < end, "no active model: {}", server.stderr());
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    let listed = list(&mut c).await;
    assert_eq!(
        listed.iter().map(|m| m.name.as_str()).collect::<Vec<_>>(),
        [
            "corrupt.onnx",
            "linear.onnx",
            "linear_reference.onnx",
            "nan_output.onnx",
            "needs_deformation.onnx",
            "tree.onnx",
            "wrong_input.onnx"
        ]
    );
    let l = model(&listed, "linear.onnx");
    assert_eq!(l.state, pb::ModelState::Active as i32);
    assert_eq!(l.features, ["velocity", "position_x"]);
    assert_eq!(l.kind, "stateless");
    assert_eq!(l.units, "N");
    assert_eq!(l.reference_steps, 0, "linear carries no reference steps");
    assert_eq!(
        model(&listed, "tree.onnx").state,
        pb::ModelState::Available as i32
    );
    // A model with reference steps: all 8 computed as at its export when it was loaded, and
    // the listing says so (0 while it was only on disk).
    assert_eq!(model(&listed, "linear_reference.onnx").reference_steps, 0);
    let r = load(&mut c, "linear_reference.onnx").await.unwrap();
    assert_eq!(r.reference_steps, 8);
    assert_eq!(
        model(&list(&mut c).await, "linear_reference.onnx").reference_steps,
        8
    );

    // Load tree, then swap to it while the loop steps.
    let t = load(&mut c, "tree.onnx").await.unwrap();
    assert_eq!(t.state, pb::ModelState::Loaded as i32);
    assert_eq!(t.features, ["position_x", "f_previous_x"]);
    stepper.wait_for(stepper.last_seq() + 20);
    let swap = activate(&mut c, "tree.onnx", false).await.unwrap();
    let effective = swap.effective_step;
    let tree_id = swap.model.as_ref().unwrap().model_id;
    assert_ne!(tree_id, linear_id);
    assert_eq!(swap.model.unwrap().active_since_step, effective);
    stepper.wait_for(effective + 50);
    let answers = stepper.answers();
    let first_linear = answers
        .iter()
        .find(|a| a.flags == 0)
        .expect("linear answered")
        .seq;
    // Before the effective step: linear; from it on: the tree. No step lost or skipped.
    check_model_answers(&answers, first_linear, effective, linear_id, linear);
    check_model_answers(&answers, effective, u64::MAX, tree_id, tree);
    for w in answers.windows(2) {
        assert_eq!(w[1].seq, w[0].seq + 1);
    }
    // Activating the active model again: a fresh engine (new id, fresh state) from a later step.
    // Named without its extension, as people type it: `tree` is `tree.onnx`.
    let again = activate(&mut c, "tree", false).await.unwrap();
    assert_eq!(again.model.as_ref().unwrap().name, "tree.onnx");
    let tree_id_again = again.model.as_ref().unwrap().model_id;
    assert!(again.effective_step > effective);
    assert_ne!(tree_id_again, tree_id);
    stepper.wait_for(again.effective_step + 20);
    let answers = stepper.answers();
    check_model_answers(&answers, effective, again.effective_step, tree_id, tree);
    check_model_answers(
        &answers,
        again.effective_step,
        u64::MAX,
        tree_id_again,
        tree,
    );
    let tree_id = tree_id_again;
    let listed = list(&mut c).await;
    assert_eq!(
        model(&listed, "linear.onnx").state,
        pb::ModelState::Loaded as i32,
        "the previous model stays loaded"
    );
    assert_eq!(
        model(&listed, "tree.onnx").state,
        pb::ModelState::Active as i32
    );

    // Each bad model is refused with its reason and code; the tree keeps serving.
    let refusals = [
        ("corrupt.onnx", Code::InvalidArgument, "corrupt"),
        ("wrong_input.onnx", Code::InvalidArgument, "wrong_inputs"),
        (
            "nan_output.onnx",
            Code::InvalidArgument,
            "non_finite_output",
        ),
        (
            "needs_deformation.onnx",
            Code::FailedPrecondition,
            "\"deformation\"",
        ),
        ("missing.onnx", Code::NotFound, "no model"),
    ];
    for (name, code, reason) in refusals {
        let before = stepper.last_seq();
        let e = load(&mut c, name).await.unwrap_err();
        assert_eq!(e.code(), code, "{name}: {e:?}");
        assert!(e.message().contains(reason), "{name}: {}", e.message());
        let e = activate(&mut c, name, true).await.unwrap_err();
        assert_eq!(e.code(), code, "{name}: {e:?}");
        stepper.wait_for(before + 10);
        check_model_answers(&stepper.answers(), before + 1, u64::MAX, tree_id, tree);
    }
    // An upload of garbage too.
    let e = c
        .load_model(pb::LoadModelRequest {
            name: "garbage.onnx".into(),
            onnx: b"not a model".to_vec(),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
    let listed = list(&mut c).await;
    for name in ["corrupt.onnx", "wrong_input.onnx", "nan_output.onnx"] {
        let m = model(&listed, name);
        assert_eq!(m.state, pb::ModelState::Failed as i32, "{m:?}");
        assert!(m.error.contains("refused"), "{m:?}");
    }
    assert_eq!(
        model(&listed, "garbage.onnx").state,
        pb::ModelState::Failed as i32
    );
    let active = c
        .get_active_model(pb::GetActiveModelRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        (active.name.as_str(), active.model_id),
        ("tree.onnx", tree_id)
    );

    // Unload: never the active model; a loaded one goes back to available.
    let e = c
        .unload_model(pb::UnloadModelRequest {
            name: "tree.onnx".into(),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition);
    c.unload_model(pb::UnloadModelRequest {
        name: "linear.onnx".into(),
    })
    .await
    .unwrap();
    let e = c
        .unload_model(pb::UnloadModelRequest {
            name: "linear.onnx".into(),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
    assert_eq!(
        model(&list(&mut c).await, "linear.onnx").state,
        pb::ModelState::Available as i32
    );
    let e = activate(&mut c, "linear.onnx", false).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "not loaded: {e:?}");

    // An upload (kept in memory) under a new name; a different file's name is refused.
    let linear_bytes = std::fs::read(dir.join("linear.onnx")).unwrap();
    let e = c
        .load_model(pb::LoadModelRequest {
            name: "tree.onnx".into(),
            onnx: linear_bytes.clone(),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    let up = c
        .load_model(pb::LoadModelRequest {
            name: "uploaded.onnx".into(),
            onnx: linear_bytes,
        })
        .await
        .unwrap()
        .into_inner()
        .model
        .unwrap();
    assert_eq!(up.state, pb::ModelState::Loaded as i32);
    assert!(
        !dir.join("uploaded.onnx").exists(),
        "uploads stay in memory"
    );
    let swap = activate(&mut c, "uploaded.onnx", false).await.unwrap();
    let up_id = swap.model.unwrap().model_id;
    stepper.wait_for(swap.effective_step + 20);
    check_model_answers(
        &stepper.answers(),
        swap.effective_step,
        u64::MAX,
        up_id,
        linear,
    );
    check_model_answers(
        &stepper.answers(),
        again.effective_step,
        swap.effective_step,
        tree_id,
        tree,
    );

    // The loop's answers all arrived in order (the thread checks each), and the server's
    // status counts its predictions.
    let lp = stepper.stop();
    let status = server
        .loop_client()
        .await
        .get_status(pb::GetStatusRequest {})
        .await
        .unwrap()
        .into_inner();
    assert!(status.predictions > 0);
    assert!(status.inference_latency.unwrap().count >= status.predictions);
    assert_eq!(status.active_model.unwrap().name, "uploaded.onnx");
    drop(lp);
}

async fn status(c: &mut LoopServiceClient<Authed>) -> pb::Status {
    c.get_status(pb::GetStatusRequest {})
        .await
        .unwrap()
        .into_inner()
}

async fn wait_status(
    c: &mut LoopServiceClient<Authed>,
    what: &str,
    ok: impl Fn(&pb::Status) -> bool,
) -> pb::Status {
    let end = Instant::now() + Duration::from_secs(5);
    loop {
        let s = status(c).await;
        if ok(&s) {
            return s;
        }
        assert!(Instant::now() < end, "{what}: {s:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// The heartbeat of this test's loop, on its own thread (as rt-loop's loop thread would).
fn heartbeat(link: shm_ring::Link, stop: Arc<AtomicBool>) -> JoinHandle<()> {
    std::thread::spawn(move || {
        while !stop.load(Ordering::Relaxed) {
            link.heartbeat();
            std::thread::sleep(Duration::from_millis(10));
        }
    })
}

fn row(step: u64, phase: u8) -> TelemetryRow {
    let s = step as f64;
    TelemetryRow {
        run_id: 7,
        step,
        time: s * 1e-4,
        f_ref: s,
        rtob_force: if step.is_multiple_of(97) { 1000.0 } else { -s },
        f_pred: 4.0 * s,
        position_x: s * 1e-6,
        velocity: -s,
        acceleration: 2.0 * s,
        f_true: 3.0 * s,
        fallback: step.is_multiple_of(2),
        phase,
        cycle_no: 2,
        ..TelemetryRow::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_experiments_and_telemetry_from_the_segment() {
    if common::fixtures().is_none() {
        return;
    }
    let dir = models_dir("status", common::fixtures().unwrap(), &["linear"]);
    let segment = segment_name("status");
    let server = ServerProcess::start("status", &dir, &segment, &[]);
    let mut c = server.loop_client().await;

    // No loop yet.
    let s = status(&mut c).await;
    assert!(!s.loop_alive);
    assert_eq!(s.experiment.unwrap().kind, "idle");
    let e = c
        .start_experiment(pb::StartExperimentRequest {
            kind: "abstraction".into(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    // No loop to take a model: refused at once, and nothing changes.
    let mut m = server.models().await;
    let e = activate(&mut m, "linear.onnx", true).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("no loop"), "{e:?}");
    let e = m
        .get_active_model(pb::GetActiveModelRequest {})
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
    let (line, body) = common::http_get(&server.http, "/api/status", server.token.as_deref());
    assert!(line.contains("200"), "{line}");
    assert!(body.contains("\"alive\":false"), "{body}");

    // A loop that heartbeats: alive.
    let mut lp = Segment::create(&segment, &loop_config())
        .unwrap()
        .loop_side()
        .unwrap();
    let beat = Arc::new(AtomicBool::new(false));
    let beating = heartbeat(lp.link.clone(), Arc::clone(&beat));
    wait_status(&mut c, "loop alive", |s| s.loop_alive).await;

    // Start: the command lands in the mailbox, parameters in order, NaN = loop default.
    c.start_experiment(pb::StartExperimentRequest {
        kind: "abstraction".into(),
        ramp_rate: Some(1.8),
        cycles: Some(3),
        f_max_start: None,
        f_max_step: Some(0.5),
    })
    .await
    .unwrap();
    let cmd = lp.commands_rx.try_recv().unwrap().expect("a command");
    let LoopCommand::Start {
        experiment, args, ..
    } = cmd
    else {
        panic!("a start, not {cmd:?}");
    };
    assert_eq!(experiment.as_str(), "abstraction");
    assert_eq!(
        args,
        ExperimentArgs {
            ramp_rate: Some(1.8),
            cycles: Some(3),
            f_max_start: None,
            f_max_step: Some(0.5),
        }
    );
    let s = status(&mut c).await;
    let x = s.experiment.unwrap();
    assert!(x.running);
    assert_eq!(x.kind, "abstraction");
    // One at a time.
    let e = c
        .start_experiment(pb::StartExperimentRequest {
            kind: "shadow".into(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("already running"), "{e:?}");
    c.stop_experiment(pb::StopExperimentRequest {})
        .await
        .unwrap();
    let cmd = lp.commands_rx.try_recv().unwrap().expect("a command");
    assert!(matches!(cmd, LoopCommand::Stop { id } if id > 0), "{cmd:?}");
    assert!(lp.commands_rx.try_recv().unwrap().is_none());

    // Telemetry written into the ring comes out of the gRPC stream, decimated by 10 with
    // min/max per bucket (the F_res spikes survive), series in their places.
    let mut stream = c
        .stream_telemetry(pb::StreamTelemetryRequest { decimation: 10 })
        .await
        .unwrap()
        .into_inner();
    let writer = std::thread::spawn(move || {
        for step in 0..3000u64 {
            lp.telemetry_tx.send(&row(step, 1));
            if step % 100 == 99 {
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        lp
    });
    let mut samples = Vec::new();
    while samples.len() < 150 {
        let s = tokio::time::timeout(Duration::from_secs(10), stream.message())
            .await
            .expect("telemetry samples")
            .unwrap()
            .expect("stream open");
        samples.push(s);
    }
    let mut lp = writer.join().unwrap();
    for w in samples.windows(2) {
        assert_eq!(w[1].step, w[0].step + u64::from(w[0].steps), "consecutive");
    }
    let mut spikes = 0;
    for s in &samples {
        let (first, last) = (s.step as f64, (s.step + u64::from(s.steps) - 1) as f64);
        assert_eq!(s.steps, 10, "{s:?}");
        assert!((s.time_s - first * 1e-4).abs() < 1e-12);
        assert_eq!((s.min[0], s.max[0]), (first, last), "F_ref");
        assert_eq!((s.min[2], s.max[2]), (4.0 * first, 4.0 * last), "F_pred");
        assert_eq!((s.min[3], s.max[3]), (first * 1e-6, last * 1e-6), "x");
        assert_eq!((s.min[4], s.max[4]), (-last, -first), "v");
        assert_eq!((s.min[5], s.max[5]), (2.0 * first, 2.0 * last), "a");
        assert_eq!((s.min[6], s.max[6]), (3.0 * first, 3.0 * last), "F_true");
        let spike = (s.step..s.step + 10).any(|k| k % 97 == 0);
        assert_eq!(s.f_res_max == 1000.0, spike, "{s:?}");
        spikes += usize::from(spike);
        assert_eq!(s.fallbacks, 5);
    }
    assert!(spikes > 5);

    // The rows tell the status: step, phase, cycle, fallbacks; a running experiment refuses
    // another start.
    let s = wait_status(&mut c, "step 2999", |s| s.step == 2999).await;
    let x = s.experiment.unwrap();
    assert!(x.running, "{x:?}");
    assert_eq!((x.phase.as_str(), x.cycle), ("ramp-up", 2));
    assert_eq!(s.fallbacks, 1500);
    assert_eq!(s.telemetry_drops, 0);
    let e = c
        .start_experiment(pb::StartExperimentRequest {
            kind: "shadow".into(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    lp.telemetry_tx.send(&row(3000, 6));
    wait_status(&mut c, "experiment done", |s| {
        s.experiment.as_ref().is_some_and(|x| x.kind == "idle")
    })
    .await;

    // The heartbeat stops (loop stuck): not alive after ~1 s; it beats again: alive.
    beat.store(true, Ordering::Relaxed);
    beating.join().unwrap();
    let t0 = Instant::now();
    wait_status(&mut c, "stuck loop not alive", |s| !s.loop_alive).await;
    assert!(t0.elapsed() > Duration::from_millis(500));
    beat.store(false, Ordering::Relaxed);
    let beating = heartbeat(lp.link.clone(), Arc::clone(&beat));
    wait_status(&mut c, "alive again", |s| s.loop_alive).await;

    // The loop exits: not alive at once (its lock is gone; no need to wait for staleness),
    // and experiments are refused.
    beat.store(true, Ordering::Relaxed);
    beating.join().unwrap();
    let t0 = Instant::now();
    drop(lp);
    wait_status(&mut c, "loop gone", |s| !s.loop_alive).await;
    assert!(
        t0.elapsed() < Duration::from_millis(900),
        "{:?}",
        t0.elapsed()
    );
    let e = c
        .start_experiment(pb::StartExperimentRequest {
            kind: "abstraction".into(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_ends_open_streams_and_websockets_quickly() {
    if common::fixtures().is_none() {
        return;
    }
    let dir = models_dir("term", common::fixtures().unwrap(), &["linear"]);
    let segment = segment_name("term");
    let lp = Segment::create(&segment, &loop_config())
        .unwrap()
        .loop_side()
        .unwrap();
    let mut server = ServerProcess::start(
        "term",
        &dir,
        &segment,
        &["--model", "linear.onnx", "--token", "s3cret"],
    );
    let stepper = StepLoop::start(lp);
    stepper.wait_for(50);
    // linear is active once the start model's wait for the loop's status block is over (this
    // loop publishes none: up to half a second)
    let mut authed = server.models_with(Some("s3cret".into())).await;
    wait_active(&mut authed, &server).await;

    // Every call needs the token: mutating calls and reads alike.
    let mut c = server.models().await;
    let e = load(&mut c, "linear.onnx").await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    let e = c.list_models(pb::ListModelsRequest {}).await.unwrap_err();
    assert_eq!(
        e.code(),
        Code::Unauthenticated,
        "a read without the token: {e:?}"
    );
    let e = server
        .loop_client()
        .await
        .stream_telemetry(pb::StreamTelemetryRequest { decimation: 1 })
        .await
        .unwrap_err();
    assert_eq!(
        e.code(),
        Code::Unauthenticated,
        "telemetry without the token: {e:?}"
    );
    let mut req = tonic::Request::new(pb::UnloadModelRequest {
        name: "linear.onnx".into(),
    });
    req.metadata_mut()
        .insert("authorization", "Bearer s3cret".parse().unwrap());
    let e = c.unload_model(req).await.unwrap_err();
    assert_eq!(
        e.code(),
        Code::FailedPrecondition,
        "authenticated, refused: {e:?}"
    );
    let mut c = server.models_with(Some("s3cret".into())).await;
    assert_eq!(list(&mut c).await.len(), 1);

    // An open gRPC telemetry stream and an open WebSocket.
    let mut stream = server
        .loop_client_with(Some("s3cret".into()))
        .await
        .stream_telemetry(pb::StreamTelemetryRequest { decimation: 1 })
        .await
        .unwrap()
        .into_inner();
    // With a token the WebSocket needs it too (docs/control-plane.md, "Safety").
    let upgrade = |auth: &str| {
        let mut ws = TcpStream::connect(&server.http).unwrap();
        write!(
            ws,
            "GET /ws/telemetry?fps=30 HTTP/1.1\r\nHost: {}\r\nConnection: Upgrade\r\n\
             Upgrade: websocket\r\nSec-WebSocket-Version: 13\r\n{auth}\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n",
            server.http
        )
        .unwrap();
        ws.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut head = [0u8; 12];
        ws.read_exact(&mut head).unwrap();
        (ws, head)
    };
    let (_, refused) = upgrade("");
    assert_eq!(
        &refused, b"HTTP/1.1 401",
        "WebSocket upgrade without the token"
    );
    let (mut ws, head) = upgrade("Authorization: Bearer s3cret\r\n");
    assert_eq!(&head, b"HTTP/1.1 101", "WebSocket upgrade");

    let (exit, took) = server.terminate();
    eprintln!("SIGTERM to exit with an open stream and WebSocket: {took:?}");
    assert!(exit.success(), "{exit}: {}", server.stderr());
    assert!(
        took < Duration::from_millis(2500),
        "shutdown took {took:?}: {}",
        server.stderr()
    );
    // The stream ended (OK status or closed connection), and the socket was closed.
    let end = tokio::time::timeout(Duration::from_secs(2), async {
        loop {
            match stream.message().await {
                Ok(Some(_)) => continue,
                other => return other.map(|_| ()),
            }
        }
    })
    .await
    .expect("the telemetry stream ended");
    let _ = end;
    let mut rest = Vec::new();
    if let Err(e) = ws.read_to_end(&mut rest) {
        // Closed with a reset is closed too; a timeout is not.
        assert!(
            !matches!(
                e.kind(),
                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
            ),
            "the WebSocket stayed open: {e}"
        );
    }
    let lp = stepper.stop();
    drop(lp);
}

/// A segment whose features are SCHEMA's, in the order `order`.
fn loop_with(segment: &SegmentName, order: &[usize]) -> LoopSide {
    let config = Config {
        feature_names: order.iter().map(|&i| SCHEMA[i].to_string()).collect(),
        ..haptics_proto::layout::config()
    };
    Segment::create(segment, &config)
        .unwrap()
        .loop_side()
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_loop_is_served_again_and_the_active_model_revalidated_for_it() {
    let Some(fixtures) = common::fixtures() else {
        return;
    };
    let dir = models_dir("reattach", fixtures, &["tree"]);
    let segment = segment_name("reattach");
    let stepper = StepLoop::start(loop_with(&segment, &[0, 1, 2, 3]));
    let server = ServerProcess::start("reattach", &dir, &segment, &["--model", "tree.onnx"]);
    let mut c = server.models().await;
    let mut l = server.loop_client().await;
    let first = loop {
        stepper.wait_for(stepper.last_seq() + 1);
        if let Some(a) = stepper.answers().iter().find(|a| a.flags == 0) {
            break *a;
        }
    };
    stepper.wait_for(first.seq + 20);
    check_model_answers(
        &stepper.answers(),
        first.seq,
        u64::MAX,
        first.model_id,
        tree,
    );
    drop(stepper.stop()); // the loop exits
    wait_status(&mut l, "first loop gone", |s| !s.loop_alive).await;

    // A second loop with the features in another order: the tree is revalidated for it (its
    // inputs are gathered from other slots) and serves from the new loop's first steps.
    let stepper = StepLoop::start_with(loop_with(&segment, &[3, 2, 0, 1]), vec![3, 2, 0, 1]);
    stepper.wait_for(200);
    let answers = stepper.answers();
    let first = answers
        .iter()
        .find(|a| a.flags == 0)
        .expect("model answers");
    assert!(first.seq < 1000, "revalidated quickly: {first:?}");
    assert!(answers.iter().filter(|a| a.seq < first.seq).all(|a| a.flags
        == infer_server::serving::inference_thread::force_flags::SCHEMA_MISMATCH
        && a.force.is_nan()));
    check_model_answers(&answers, first.seq, u64::MAX, first.model_id, tree);
    let s = wait_status(&mut l, "second loop alive", |s| s.loop_alive).await;
    assert_eq!(s.active_model.unwrap().name, "tree.onnx");
    drop(stepper.stop());
    wait_status(&mut l, "second loop gone", |s| !s.loop_alive).await;

    // A third loop without position_x: the tree cannot serve it. Every step is answered with
    // NaN + SCHEMA_MISMATCH (the loop renders its fallback), the model is listed as failed
    // with the reason, and there is no active model.
    let stepper = StepLoop::start_with(loop_with(&segment, &[1, 3]), vec![1, 3]);
    stepper.wait_for(100);
    let end = Instant::now() + Duration::from_secs(5);
    let failed = loop {
        let m = list(&mut c).await;
        let t = model(&m, "tree.onnx").clone();
        if t.state == pb::ModelState::Failed as i32 {
            break t;
        }
        assert!(Instant::now() < end, "{t:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert!(failed.error.contains("position_x"), "{failed:?}");
    let e = c
        .get_active_model(pb::GetActiveModelRequest {})
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
    assert!(stepper.answers().iter().all(|a| a.flags
        == infer_server::serving::inference_thread::force_flags::SCHEMA_MISMATCH
        && a.force.is_nan()));
    drop(stepper.stop());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hundred_swaps_lose_no_step_and_each_takes_effect_at_its_reported_step() {
    let Some(fixtures) = common::fixtures() else {
        return;
    };
    let dir = models_dir("swap100", fixtures, &["linear", "tree"]);
    let segment = segment_name("swap100");
    let stepper = StepLoop::start(loop_with(&segment, &[0, 1, 2, 3]));
    let server = ServerProcess::start("swap100", &dir, &segment, &["--model", "linear.onnx"]);
    let mut c = server.models().await;
    load(&mut c, "tree.onnx").await.unwrap();
    while !stepper.answers().iter().any(|a| a.flags == 0) {
        stepper.wait_for(stepper.last_seq() + 1);
    }
    // (effective step, model id, formula) of every swap.
    let mut swaps: Vec<(u64, u32, Formula)> = Vec::new();
    for i in 0..100 {
        let (name, f): (&str, Formula) = if i % 2 == 0 {
            ("tree.onnx", tree)
        } else {
            ("linear.onnx", linear)
        };
        let a = activate(&mut c, name, false).await.unwrap();
        if let Some(&(prev, _, _)) = swaps.last() {
            assert!(a.effective_step > prev, "swap {i}: {a:?}");
        }
        swaps.push((a.effective_step, a.model.unwrap().model_id, f));
    }
    stepper.wait_for(swaps.last().unwrap().0 + 10);
    let answers = stepper.stop_and_answers();
    for w in answers.windows(2) {
        assert_eq!(w[1].seq, w[0].seq + 1, "no step lost");
    }
    for (i, &(from, id, f)) in swaps.iter().enumerate() {
        let until = swaps.get(i + 1).map_or(u64::MAX, |s| s.0);
        check_model_answers(&answers, from, until, id, f);
    }
    let ids: std::collections::HashSet<u32> = swaps.iter().map(|s| s.1).collect();
    assert_eq!(ids.len(), 100, "every activation is a new generation");
    eprintln!(
        "100 swaps over steps {}..{}",
        swaps[0].0,
        swaps.last().unwrap().0
    );
}

/// A gRPC client that is not ours: Python grpcio with no .proto and no stubs
/// (infer-server/control-plane/tests/py/grpc_reflection_client.py), against the real server: services
/// through reflection v1 and v1alpha, GetStatus, ListModels, the token rule, an activation
/// with its effective step, a bad name, health.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_python_grpc_client_uses_the_real_server_through_reflection() {
    let Some(fixtures) = common::fixtures() else {
        return;
    };
    let dir = models_dir("py", fixtures, &[]);
    std::fs::copy(fixtures.join("linear.onnx"), dir.join("a.onnx")).unwrap();
    let segment = segment_name("py");
    let stepper = StepLoop::start(loop_with(&segment, &[0, 1, 2, 3]));
    let server = ServerProcess::start("py", &dir, &segment, &["--token", "py-token"]);
    stepper.wait_for(10);
    let script =
        common::repo_root().join("infer-server/control-plane/tests/py/grpc_reflection_client.py");
    let out = Command::new(common::python())
        .arg(&script)
        .arg(server.grpc.trim_start_matches("http://"))
        .arg("py-token")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "python failed:\n{stderr}");
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in ["services_v1", "services_v1alpha"] {
        let got = r[key].to_string();
        for svc in [
            "grpc.health.v1.Health",
            "grpc.reflection.v1.ServerReflection",
            "grpc.reflection.v1alpha.ServerReflection",
            "haptics.v1.LoopService",
            "haptics.v1.ModelService",
        ] {
            assert!(got.contains(svc), "{key}: {svc} missing from {got}");
        }
    }
    assert_eq!(r["status"]["loop_alive"], true, "{}", r["status"]);
    assert_eq!(r["status"]["token_required"], true);
    assert_eq!(r["models"]["models"][0]["name"], "a.onnx");
    assert_eq!(r["activate_without_token"], "UNAUTHENTICATED");
    assert_eq!(r["status_without_token"], "UNAUTHENTICATED");
    assert_eq!(r["activate"]["model"]["name"], "a.onnx");
    let eff: u64 = r["activate"]["effective_step"]
        .as_str()
        .unwrap()
        .parse()
        .unwrap();
    let id = r["activate"]["model"]["model_id"].as_u64().unwrap() as u32;
    stepper.wait_for(eff + 10);
    check_model_answers(&stepper.answers(), eff, u64::MAX, id, linear);
    assert!(stepper
        .answers()
        .iter()
        .filter(|a| a.seq < eff)
        .all(|a| a.flags == infer_server::serving::inference_thread::force_flags::NO_MODEL));
    assert_eq!(r["bad_name"], "INVALID_ARGUMENT");
    assert_eq!(r["health"], "SERVING");
    drop(stepper.stop());
}

/// A stateful model whose state steps at another period than the loop's (`haptics.step_s`
/// against the nominal rate in the loop's status block) is refused when activated, and the
/// active model stays; one exported for this loop's rate is served.
#[tokio::test(flavor = "multi_thread")]
async fn a_model_stepped_for_another_loop_rate_is_refused() {
    use haptics_proto::LoopStatus;
    let Some(fixtures) = common::fixtures() else {
        return;
    };
    let dir = models_dir(
        "step",
        fixtures,
        &["linear", "stepped_5khz", "stepped_10khz"],
    );
    let segment = segment_name("step");
    let lp = loop_publishing(
        &segment,
        &LoopStatus {
            rate_hz: 10_000.0,
            ..LoopStatus::default()
        },
    );
    let server = ServerProcess::start("step", &dir, &segment, &["--model", "linear.onnx"]);
    let stepper = StepLoop::start(lp);
    let mut c = server.models().await;
    let end = Instant::now() + Duration::from_secs(20);
    let linear_id = loop {
        if let Ok(m) = c.get_active_model(pb::GetActiveModelRequest {}).await {
            break m.into_inner().model_id;
        }
        assert!(Instant::now() < end, "no active model: {}", server.stderr());
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    stepper.wait_for(stepper.last_seq() + 20);

    let e = activate(&mut c, "stepped_5khz.onnx", true)
        .await
        .expect_err("a 5 kHz state beside a 10 kHz loop must be refused");
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    for part in [
        "haptics.step_s",
        "5000 Hz",
        "10000 Hz",
        "2.000x",
        "nothing changed",
    ] {
        assert!(
            e.message().contains(part),
            "{part:?} not in {:?}",
            e.message()
        );
    }
    let active = c
        .get_active_model(pb::GetActiveModelRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(active.model_id, linear_id, "the active model stays");
    let listed = list(&mut c).await;
    assert_eq!(
        model(&listed, "stepped_5khz.onnx").state,
        pb::ModelState::Loaded as i32,
        "the refused model stays loaded"
    );

    let ok = activate(&mut c, "stepped_10khz.onnx", true).await.unwrap();
    assert_ne!(ok.model.unwrap().model_id, linear_id);
}

/// A model whose training features were computed with other filters than the loop's
/// (`haptics.feature_gains` against the gains in the loop's status block) is served, and the
/// server says so on stderr and in the swap's answer, naming both.
#[tokio::test(flavor = "multi_thread")]
async fn a_model_of_other_feature_filters_is_served_and_named() {
    use haptics_proto::LoopStatus;
    let Some(fixtures) = common::fixtures() else {
        return;
    };
    let dir = models_dir("gains", fixtures, &["linear", "linear_other_filters"]);
    let segment = segment_name("gains");
    let lp = loop_publishing(
        &segment,
        &LoopStatus {
            rate_hz: 10_000.0,
            velocity_gain_rad_s: 30.0,
            acceleration_gain_rad_s: 100.0,
            ..LoopStatus::default()
        },
    );
    let server = ServerProcess::start("gains", &dir, &segment, &["--model", "linear.onnx"]);
    let stepper = StepLoop::start(lp);
    let mut c = server.models().await;
    wait_active(&mut c, &server).await;
    stepper.wait_for(stepper.last_seq() + 20);
    assert!(
        !server.stderr().contains("other filters"),
        "{}",
        server.stderr()
    );
    let r = activate(&mut c, "linear_other_filters.onnx", true)
        .await
        .expect("served, not refused");
    // in the swap's answer too (hapticctl prints it)
    assert!(
        r.warnings.len() == 1 && r.warnings[0].contains("velocity at g_v 10"),
        "{:?}",
        r.warnings
    );
    let said = server.stderr();
    assert!(
        said.contains("warning: model linear_other_filters.onnx")
            && said.contains("velocity at g_v 10")
            && said.contains("the loop's 30"),
        "{said}"
    );
    drop(stepper.stop());
}

/// The start model (`--model`) is checked the same way: the server waits for the loop's status
/// block before activating it, and refuses one stepped for another rate (it serves no model, and
/// says why).
#[tokio::test(flavor = "multi_thread")]
async fn a_start_model_stepped_for_another_loop_rate_is_refused() {
    use haptics_proto::LoopStatus;
    let Some(fixtures) = common::fixtures() else {
        return;
    };
    let dir = models_dir("step-start", fixtures, &["stepped_5khz"]);
    let segment = segment_name("step-start");
    let lp = loop_publishing(
        &segment,
        &LoopStatus {
            rate_hz: 10_000.0,
            ..LoopStatus::default()
        },
    );
    let server = ServerProcess::start(
        "step-start",
        &dir,
        &segment,
        &["--model", "stepped_5khz.onnx"],
    );
    let _stepper = StepLoop::start(lp);
    let end = Instant::now() + Duration::from_secs(20);
    while !server.stderr().contains("cannot be served by this loop") {
        assert!(Instant::now() < end, "no refusal: {}", server.stderr());
        std::thread::sleep(Duration::from_millis(20));
    }
    let err = server.stderr();
    assert!(
        err.contains("haptics.step_s") && err.contains("5000 Hz"),
        "{err}"
    );
    let mut c = server.models().await;
    assert!(
        c.get_active_model(pb::GetActiveModelRequest {})
            .await
            .is_err(),
        "no model is active"
    );
}
