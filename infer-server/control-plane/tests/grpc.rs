//! Every gRPC call of haptics.v1 against the control plane over a simulated backend.
mod common;

use std::time::Duration;

use common::*;
use control_plane::pb;
use control_plane::pb::loop_service_client::LoopServiceClient;
use control_plane::pb::model_service_client::ModelServiceClient;
use control_plane::Config;
use control_plane_sim::{model_file, nan_model_file, SimBackend, SPIKE_EVERY, SPIKE_N};
use tonic::{Code, Request};

async fn clients(
    s: &TestServer,
) -> (
    ModelServiceClient<tonic::transport::Channel>,
    LoopServiceClient<tonic::transport::Channel>,
) {
    let models = ModelServiceClient::connect(s.grpc_url()).await.unwrap();
    let looper = LoopServiceClient::connect(s.grpc_url()).await.unwrap();
    (models, looper)
}

fn state_of(list: &pb::ListModelsResponse, name: &str) -> pb::ModelState {
    list.models
        .iter()
        .find(|m| m.name == name)
        .unwrap_or_else(|| panic!("{name} not listed"))
        .state()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn models_list_load_activate_unload() {
    let s = start().await;
    let (mut models, _) = clients(&s).await;

    let list = models
        .list_models(pb::ListModelsRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(list.models.len(), 2);
    assert_eq!(state_of(&list, "a.onnx"), pb::ModelState::Available);

    let err = models
        .get_active_model(pb::GetActiveModelRequest {})
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::NotFound);

    let loaded = models
        .load_model(pb::LoadModelRequest {
            name: "a.onnx".into(),
            onnx: vec![],
        })
        .await
        .unwrap()
        .into_inner()
        .model
        .unwrap();
    assert_eq!(loaded.state(), pb::ModelState::Loaded);
    assert_eq!(loaded.features, vec!["position_x", "velocity"]);
    assert_eq!(loaded.kind, "stateless");
    assert!(loaded.model_id > 0);

    // Not loaded and not asked to load: refused.
    let err = models
        .activate_model(pb::ActivateModelRequest {
            name: "b.onnx".into(),
            load_if_needed: false,
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::FailedPrecondition, "{err:?}");

    let step_before = s.backend.step();
    let a = models
        .activate_model(pb::ActivateModelRequest {
            name: "b.onnx".into(),
            load_if_needed: true,
        })
        .await
        .unwrap()
        .into_inner();
    assert!(a.effective_step >= step_before);
    assert_eq!(s.backend.swaps(), vec![a.effective_step]);
    let active = models
        .get_active_model(pb::GetActiveModelRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(active.name, "b.onnx");
    assert_eq!(active.state(), pb::ModelState::Active);
    assert_eq!(active.active_since_step, a.effective_step);

    // Swap to a: b stays loaded.
    let a2 = models
        .activate_model(pb::ActivateModelRequest {
            name: "a.onnx".into(),
            load_if_needed: false,
        })
        .await
        .unwrap()
        .into_inner();
    assert!(a2.effective_step >= a.effective_step);
    let list = models
        .list_models(pb::ListModelsRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(state_of(&list, "a.onnx"), pb::ModelState::Active);
    assert_eq!(state_of(&list, "b.onnx"), pb::ModelState::Loaded);

    let err = models
        .unload_model(pb::UnloadModelRequest {
            name: "a.onnx".into(),
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::FailedPrecondition);
    models
        .unload_model(pb::UnloadModelRequest {
            name: "b.onnx".into(),
        })
        .await
        .unwrap();
    let list = models
        .list_models(pb::ListModelsRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(state_of(&list, "b.onnx"), pb::ModelState::Available);
    let err = models
        .unload_model(pb::UnloadModelRequest {
            name: "b.onnx".into(),
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::NotFound);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_models_are_refused_with_the_right_code_and_the_active_one_keeps_serving() {
    let s = start().await;
    let (mut models, mut looper) = clients(&s).await;
    models
        .activate_model(pb::ActivateModelRequest {
            name: "a.onnx".into(),
            load_if_needed: true,
        })
        .await
        .unwrap();

    let cases: [(&str, Vec<u8>, Code, &str); 4] = [
        (
            "corrupt.onnx",
            b"\x08\x01garbage".to_vec(),
            Code::InvalidArgument,
            "not a model file",
        ),
        (
            "wrong-inputs.onnx",
            model_file(&["position_x", "jerk"], 1.0),
            Code::FailedPrecondition,
            "jerk",
        ),
        ("nan.onnx", nan_model_file(), Code::InvalidArgument, "NaN"),
        (
            "../escape.onnx",
            model_file(&["position_x"], 1.0),
            Code::InvalidArgument,
            "not a path",
        ),
    ];
    for (name, bytes, code, why) in cases {
        let err = models
            .load_model(pb::LoadModelRequest {
                name: name.into(),
                onnx: bytes,
            })
            .await
            .unwrap_err();
        assert_eq!(err.code(), code, "{name}: {err:?}");
        assert!(err.message().contains(why), "{name}: {}", err.message());
        let active = models
            .get_active_model(pb::GetActiveModelRequest {})
            .await
            .unwrap()
            .into_inner();
        assert_eq!(active.name, "a.onnx", "still serving after {name}");
    }
    // A failed load is listed with its reason.
    let list = models
        .list_models(pb::ListModelsRequest {})
        .await
        .unwrap()
        .into_inner();
    let nan = list.models.iter().find(|m| m.name == "nan.onnx").unwrap();
    assert_eq!(nan.state(), pb::ModelState::Failed);
    assert!(nan.error.contains("NaN"));
    // Activating a failed model fails the same way, and changes nothing.
    let err = models
        .activate_model(pb::ActivateModelRequest {
            name: "nan.onnx".into(),
            load_if_needed: true,
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::InvalidArgument);
    let err = models
        .load_model(pb::LoadModelRequest {
            name: "missing.onnx".into(),
            onnx: vec![],
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::NotFound);
    let status = looper
        .get_status(pb::GetStatusRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(status.active_model.unwrap().name, "a.onnx");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn upload_works_and_the_size_limit_is_enforced() {
    let config = Config {
        max_upload_bytes: 4096,
        ..test_config()
    };
    let s = start_with(config, SimBackend::with_two_models(RATE_HZ)).await;
    let (mut models, _) = clients(&s).await;

    let mut ok = model_file(&["position_x"], 3.0);
    ok.resize(4096, b' ');
    let m = models
        .load_model(pb::LoadModelRequest {
            name: "up.onnx".into(),
            onnx: ok,
        })
        .await
        .unwrap()
        .into_inner()
        .model
        .unwrap();
    assert_eq!((m.name.as_str(), m.size_bytes), ("up.onnx", 4096));

    // Just over: our message, which says the limit.
    let err = models
        .load_model(pb::LoadModelRequest {
            name: "big.onnx".into(),
            onnx: vec![b' '; 4097],
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::ResourceExhausted);
    assert!(
        err.message().contains("limit of 4096 bytes"),
        "{}",
        err.message()
    );
    // Far over: tonic refuses it while decoding (OUT_OF_RANGE), before the handler runs.
    let err = models
        .load_model(pb::LoadModelRequest {
            name: "huge.onnx".into(),
            onnx: vec![0; 1 << 20],
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::OutOfRange, "{err:?}");
    assert!(err.message().contains("too large"), "{err:?}");
    let list = models
        .list_models(pb::ListModelsRequest {})
        .await
        .unwrap()
        .into_inner();
    assert!(list
        .models
        .iter()
        .all(|m| m.name != "big.onnx" && m.name != "huge.onnx"));
    // Clients can learn the limit before sending.
    let mut looper = LoopServiceClient::connect(s.grpc_url()).await.unwrap();
    let st = looper
        .get_status(pb::GetStatusRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(st.max_upload_bytes, 4096);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mutating_calls_need_the_token_when_one_is_set() {
    let config = Config {
        token: Some("s3cret".into()),
        ..test_config()
    };
    let s = start_with(config, SimBackend::with_two_models(RATE_HZ)).await;
    let (mut models, mut looper) = clients(&s).await;
    fn with<T>(msg: T, token: Option<&str>) -> Request<T> {
        let mut r = Request::new(msg);
        if let Some(t) = token {
            r.metadata_mut()
                .insert("authorization", format!("Bearer {t}").parse().unwrap());
        }
        r
    }
    for token in [None, Some("wrong")] {
        let load = models
            .load_model(with(
                pb::LoadModelRequest {
                    name: "a.onnx".into(),
                    onnx: vec![],
                },
                token,
            ))
            .await;
        let act = models
            .activate_model(with(
                pb::ActivateModelRequest {
                    name: "a.onnx".into(),
                    load_if_needed: true,
                },
                token,
            ))
            .await;
        let unload = models
            .unload_model(with(
                pb::UnloadModelRequest {
                    name: "a.onnx".into(),
                },
                token,
            ))
            .await;
        let start = looper
            .start_experiment(with(
                pb::StartExperimentRequest {
                    kind: "shadow".into(),
                    ..Default::default()
                },
                token,
            ))
            .await;
        let stop = looper
            .stop_experiment(with(pb::StopExperimentRequest {}, token))
            .await;
        for (what, code) in [
            ("load", load.unwrap_err().code()),
            ("activate", act.unwrap_err().code()),
            ("unload", unload.unwrap_err().code()),
            ("start", start.unwrap_err().code()),
            ("stop", stop.unwrap_err().code()),
        ] {
            assert_eq!(code, Code::Unauthenticated, "{what} with {token:?}");
        }
    }
    // An upload far over the decoding limit is refused for its missing token, before its body
    // is read (a decoded one would fail with OUT_OF_RANGE instead).
    let err = models
        .load_model(with(
            pb::LoadModelRequest {
                name: "big.onnx".into(),
                onnx: vec![0; 80 << 20],
            },
            None,
        ))
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::Unauthenticated, "{err:?}");
    assert!(s.backend.swaps().is_empty(), "nothing reached the backend");
    assert!(s.backend.last_experiment().is_none());
    // Reading live data or provenance needs the token too (issue 21): status, models, the
    // active model, telemetry.
    for token in [None, Some("wrong")] {
        let codes = [
            (
                "list",
                models
                    .list_models(with(pb::ListModelsRequest {}, token))
                    .await
                    .unwrap_err()
                    .code(),
            ),
            (
                "active",
                models
                    .get_active_model(with(pb::GetActiveModelRequest {}, token))
                    .await
                    .unwrap_err()
                    .code(),
            ),
            (
                "status",
                looper
                    .get_status(with(pb::GetStatusRequest {}, token))
                    .await
                    .unwrap_err()
                    .code(),
            ),
            (
                "telemetry",
                looper
                    .stream_telemetry(with(pb::StreamTelemetryRequest { decimation: 10 }, token))
                    .await
                    .map(|_| ())
                    .unwrap_err()
                    .code(),
            ),
        ];
        for (what, code) in codes {
            assert_eq!(code, Code::Unauthenticated, "{what} with {token:?}");
        }
    }
    models
        .list_models(with(pb::ListModelsRequest {}, Some("s3cret")))
        .await
        .unwrap();
    let st = looper
        .get_status(with(pb::GetStatusRequest {}, Some("s3cret")))
        .await
        .unwrap()
        .into_inner();
    assert!(st.token_required);
    // With the token everything works.
    models
        .activate_model(with(
            pb::ActivateModelRequest {
                name: "a.onnx".into(),
                load_if_needed: true,
            },
            Some("s3cret"),
        ))
        .await
        .unwrap();
    looper
        .start_experiment(with(
            pb::StartExperimentRequest {
                kind: "shadow".into(),
                ..Default::default()
            },
            Some("s3cret"),
        ))
        .await
        .unwrap();
    assert_eq!(s.backend.swaps().len(), 1);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_and_experiments() {
    let s = start().await;
    let (_, mut looper) = clients(&s).await;
    let st = looper
        .get_status(pb::GetStatusRequest {})
        .await
        .unwrap()
        .into_inner();
    assert!(st.loop_alive);
    assert_eq!(
        (st.mode.as_str(), st.clock.as_str(), st.board.as_str()),
        ("idle", "realtime", "sim")
    );
    assert_eq!(st.rate_hz, RATE_HZ);
    assert!(!st.token_required);
    assert!(st.active_model.is_none());
    tokio::time::sleep(Duration::from_millis(30)).await;
    let st2 = looper
        .get_status(pb::GetStatusRequest {})
        .await
        .unwrap()
        .into_inner();
    assert!(st2.step > st.step, "the loop runs");
    assert!(st2.fallbacks > 0, "no model: every step is a fallback");

    looper
        .start_experiment(pb::StartExperimentRequest {
            kind: "abstraction".into(),
            ramp_rate: Some(2.1),
            cycles: Some(10),
            f_max_start: None,
            f_max_step: Some(0.5),
        })
        .await
        .unwrap();
    let req = s.backend.last_experiment().unwrap();
    assert_eq!(req.kind, control_plane::ExperimentKind::Abstraction);
    assert_eq!(
        (req.ramp_rate, req.cycles, req.f_max_start, req.f_max_step),
        (Some(2.1), Some(10), None, Some(0.5))
    );
    let st = looper
        .get_status(pb::GetStatusRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(st.mode, "abstraction");
    let exp = st.experiment.unwrap();
    assert!(exp.running);
    assert_eq!(exp.phase, "ramp-up");

    let err = looper
        .start_experiment(pb::StartExperimentRequest {
            kind: "shadow".into(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::FailedPrecondition, "already running");
    looper
        .stop_experiment(pb::StopExperimentRequest {})
        .await
        .unwrap();
    assert_eq!(
        looper
            .get_status(pb::GetStatusRequest {})
            .await
            .unwrap()
            .into_inner()
            .mode,
        "idle"
    );

    for bad in [
        pb::StartExperimentRequest {
            kind: "dance".into(),
            ..Default::default()
        },
        pb::StartExperimentRequest {
            kind: "abstraction".into(),
            ramp_rate: Some(-1.0),
            ..Default::default()
        },
        pb::StartExperimentRequest {
            kind: "abstraction".into(),
            cycles: Some(0),
            ..Default::default()
        },
    ] {
        let err = looper.start_experiment(bad).await.unwrap_err();
        assert_eq!(err.code(), Code::InvalidArgument, "{err:?}");
    }

    s.backend.set_loop_alive(false);
    let st = looper
        .get_status(pb::GetStatusRequest {})
        .await
        .unwrap()
        .into_inner();
    assert!(!st.loop_alive);
    let err = looper
        .start_experiment(pb::StartExperimentRequest {
            kind: "shadow".into(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::FailedPrecondition);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn telemetry_is_decimated_with_min_max_and_spikes_survive() {
    let s = start().await;
    let (_, mut looper) = clients(&s).await;
    let mut stream = looper
        .stream_telemetry(pb::StreamTelemetryRequest { decimation: 50 })
        .await
        .unwrap()
        .into_inner();
    let mut samples = Vec::new();
    while samples.len() < 120 {
        let sample = tokio::time::timeout(Duration::from_secs(5), stream.message())
            .await
            .expect("telemetry flows")
            .unwrap()
            .unwrap();
        samples.push(sample);
    }
    let mut spikes = 0;
    for w in samples.windows(2) {
        assert_eq!(w[0].steps, 50);
        assert_eq!(w[1].step, w[0].step + 50, "contiguous buckets");
        assert!((w[1].time_s - w[0].time_s - 50.0 / RATE_HZ).abs() < 1e-9);
    }
    for x in &samples {
        let n = control_plane::telemetry::N_SERIES;
        assert_eq!((x.min.len(), x.max.len()), (n, n));
        assert_eq!(x.f_res_max, x.max[1]);
        assert_eq!(x.f_res_min, x.min[1]);
        assert!(x
            .min
            .iter()
            .zip(&x.max)
            .all(|(lo, hi)| lo <= hi || lo.is_nan()));
        assert!(x.fallback && x.fallbacks == 50, "no model active");
        assert!(x.f_pred.is_nan());
        let has_spike = (x.step..x.step + 50).any(|i| i % SPIKE_EVERY == 0);
        if has_spike {
            spikes += 1;
            assert!(
                x.f_res_max > SPIKE_N / 2.0,
                "spike at bucket {} hidden: max {}",
                x.step,
                x.f_res_max
            );
        } else {
            assert!(x.f_res_max < SPIKE_N / 2.0, "bucket {}", x.step);
        }
    }
    assert!(spikes >= 5, "the window holds spikes ({spikes})");

    // Decimation 0 means 100.
    let mut stream = looper
        .stream_telemetry(pb::StreamTelemetryRequest { decimation: 0 })
        .await
        .unwrap()
        .into_inner();
    let x = stream.message().await.unwrap().unwrap();
    assert_eq!(x.steps, 100);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_reports_serving() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};
    let s = start().await;
    let channel = tonic::transport::Endpoint::from_shared(s.grpc_url())
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut health = HealthClient::new(channel);
    for service in ["", "haptics.v1.ModelService", "haptics.v1.LoopService"] {
        let r = health
            .check(HealthCheckRequest {
                service: service.into(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.status(), ServingStatus::Serving, "{service:?}");
    }
    let err = health
        .check(HealthCheckRequest {
            service: "nope.Service".into(),
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::NotFound);
    s.stop().await;
}

/// 100 swaps while the simulated loop runs at 10 kHz and a client streams every step: no step
/// is missing from the stream, and every step is answered by the model that the reported
/// effective steps say (a.onnx has gain 1, b.onnx gain 2).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hundred_swaps_report_the_step_they_take_effect() {
    let s = start().await;
    let (mut models, mut looper) = clients(&s).await;
    for name in ["a.onnx", "b.onnx"] {
        models
            .load_model(pb::LoadModelRequest {
                name: name.into(),
                onnx: vec![],
            })
            .await
            .unwrap();
    }
    let mut stream = looper
        .stream_telemetry(pb::StreamTelemetryRequest { decimation: 1 })
        .await
        .unwrap()
        .into_inner();
    let first = stream.message().await.unwrap().unwrap().step;
    let mut swaps = Vec::new();
    for i in 0..100 {
        let name = if i % 2 == 0 { "a.onnx" } else { "b.onnx" };
        let r = models
            .activate_model(pb::ActivateModelRequest {
                name: name.into(),
                load_if_needed: false,
            })
            .await
            .unwrap()
            .into_inner();
        swaps.push((r.effective_step, if i % 2 == 0 { 1.0 } else { 2.0 }));
        tokio::time::sleep(Duration::from_millis(3)).await;
    }
    let last_swap = swaps.last().unwrap().0;
    assert!(swaps.windows(2).all(|w| w[1].0 >= w[0].0));
    let mut expected_step = first + 1;
    let mut checked = 0;
    while expected_step < last_swap + 100 {
        let x = tokio::time::timeout(Duration::from_secs(5), stream.message())
            .await
            .expect("telemetry keeps up")
            .unwrap()
            .unwrap();
        assert_eq!(x.step, expected_step, "no lost step");
        expected_step += 1;
        // The model answering this step: the last swap effective at or before it.
        let gain = swaps
            .iter()
            .rev()
            .find(|(eff, _)| *eff <= x.step)
            .map(|(_, g)| *g);
        match gain {
            None => assert!(
                x.f_pred.is_nan() && x.fallback,
                "step {} before any swap",
                x.step
            ),
            Some(g) => {
                assert!(!x.fallback);
                assert_eq!(
                    x.f_pred,
                    g * x.f_true,
                    "step {} answered by gain {g}",
                    x.step
                );
                // the object's own force has its field and its series (the last)
                assert_eq!(x.f_object, x.f_true);
                assert_eq!(x.max.last(), Some(&x.f_object));
                checked += 1;
            }
        }
    }
    assert!(checked > 100);
    assert_eq!(
        s.backend.swaps(),
        swaps.iter().map(|(e, _)| *e).collect::<Vec<_>>()
    );
    s.stop().await;
}
