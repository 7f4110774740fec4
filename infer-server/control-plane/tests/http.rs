//! The HTTP side: /api/* JSON, tokens, origins, uploads, /metrics and the page.
mod common;

use common::*;
use control_plane::Config;
use control_plane_sim::{model_file, SimBackend};
use serde_json::Value;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_object_has_every_field_the_page_reads() {
    let s = start().await;
    let (code, st) = http_json(&s, "GET", "/api/status", &[], vec![]).await;
    assert_eq!(code, 200);
    assert!(st["server"]["version"].is_string());
    assert!(st["server"]["uptime_s"].is_number());
    assert_eq!(st["server"]["token_required"], false);
    let l = &st["loop"];
    assert_eq!(l["alive"], true);
    assert_eq!(l["clock"], "realtime");
    assert_eq!(l["board"], "sim");
    assert_eq!(l["rate_hz"], RATE_HZ);
    for k in ["steps", "deadline_misses", "fallbacks"] {
        assert!(l[k].is_u64(), "{k}");
    }
    for k in ["p50", "p99", "p999"] {
        assert!(l["latency_us"][k].is_number(), "{k}");
    }
    assert_eq!(l["experiment"]["kind"], "idle");
    assert_eq!(l["experiment"]["running"], false);
    assert!(st["active_model"].is_null());

    let (code, a) = http_json(&s, "POST", "/api/models/b.onnx/activate", &[], vec![]).await;
    assert_eq!(code, 200, "{a}");
    let eff = a["effective_step"].as_u64().unwrap();
    assert_eq!(a["model"]["state"], "active");
    let (_, st) = http_json(&s, "GET", "/api/status", &[], vec![]).await;
    let m = &st["active_model"];
    assert_eq!(m["name"], "b.onnx");
    assert_eq!(m["kind"], "stateless");
    assert_eq!(m["features"], serde_json::json!(["position_x", "velocity"]));
    assert_eq!(m["since_step"].as_u64(), Some(eff));
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn model_api_and_error_statuses() {
    let s = start().await;
    let (code, list) = http_json(&s, "GET", "/api/models", &[], vec![]).await;
    assert_eq!(code, 200);
    let list = list.as_array().unwrap().clone();
    assert_eq!(list.len(), 2);
    assert_eq!(list[0]["name"], "a.onnx");
    assert_eq!(list[0]["state"], "available");
    assert!(list[0].get("error").is_none());

    let (code, m) = http_json(&s, "POST", "/api/models/a.onnx/load", &[], vec![]).await;
    assert_eq!((code, m["state"].as_str()), (200, Some("loaded")));
    let (code, a) = http_json(
        &s,
        "POST",
        "/api/models/a.onnx/activate?load_if_needed=false",
        &[],
        vec![],
    )
    .await;
    assert_eq!(code, 200, "{a}");
    let (code, e) = http_json(
        &s,
        "POST",
        "/api/models/b.onnx/activate?load_if_needed=false",
        &[],
        vec![],
    )
    .await;
    assert_eq!(code, 412, "{e}");
    assert!(e["error"].as_str().unwrap().contains("not loaded"));

    // Upload through the body: a model with a feature the loop lacks.
    let (code, e) = http_json(
        &s,
        "POST",
        "/api/models/x.onnx/load",
        &[],
        model_file(&["jerk"], 1.0),
    )
    .await;
    assert_eq!(code, 412, "{e}");
    let (code, e) = http_json(
        &s,
        "POST",
        "/api/models/y.onnx/load",
        &[],
        b"garbage".to_vec(),
    )
    .await;
    assert_eq!(code, 400, "{e}");
    let (code, e) = http_json(&s, "POST", "/api/models/nope.onnx/load", &[], vec![]).await;
    assert_eq!(code, 404, "{e}");
    let (code, e) = http_json(&s, "POST", "/api/models/..%2Fetc/load", &[], vec![]).await;
    assert_eq!(code, 400, "{e}");
    let (code, up) = http_json(
        &s,
        "POST",
        "/api/models/z.onnx/load",
        &[],
        model_file(&["velocity"], 2.0),
    )
    .await;
    assert_eq!((code, up["state"].as_str()), (200, Some("loaded")), "{up}");

    let (code, e) = http_json(&s, "POST", "/api/models/a.onnx/unload", &[], vec![]).await;
    assert_eq!(code, 412, "{e}");
    let (code, _) = http_json(&s, "POST", "/api/models/z.onnx/unload", &[], vec![]).await;
    assert_eq!(code, 200);
    let (code, active) = http_json(&s, "GET", "/api/models/active", &[], vec![]).await;
    assert_eq!((code, active["name"].as_str()), (200, Some("a.onnx")));
    let (code, e) = http_json(&s, "GET", "/api/nothing/here", &[], vec![]).await;
    assert_eq!(code, 404, "{e}");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn experiments_over_http() {
    let s = start().await;
    let body = br#"{"kind":"abstraction","ramp_rate":2.1,"cycles":10}"#.to_vec();
    let (code, r) = http_json(&s, "POST", "/api/experiment/start", &[], body).await;
    assert_eq!((code, r), (200, serde_json::json!({})));
    let req = s.backend.last_experiment().unwrap();
    assert_eq!(
        (req.ramp_rate, req.cycles, req.f_max_start),
        (Some(2.1), Some(10), None)
    );
    let (_, st) = http_json(&s, "GET", "/api/status", &[], vec![]).await;
    assert_eq!(st["loop"]["experiment"]["kind"], "abstraction");
    assert_eq!(st["loop"]["experiment"]["running"], true);
    for bad in [
        &br#"{"kind":"dance"}"#[..],
        br#"{"kind":"shadow","ramp_rate":-2}"#,
        br#"{"kind":"shadow","speed":3}"#,
        b"not json",
    ] {
        let (code, e) = http_json(&s, "POST", "/api/experiment/start", &[], bad.to_vec()).await;
        assert_eq!(code, 400, "{e}");
        assert!(e["error"].is_string());
    }
    let (code, _) = http_json(&s, "POST", "/api/experiment/stop", &[], vec![]).await;
    assert_eq!(code, 200);
    let (_, st) = http_json(&s, "GET", "/api/status", &[], vec![]).await;
    assert_eq!(st["loop"]["experiment"]["running"], false);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn token_origin_and_upload_limit() {
    let config = Config {
        token: Some("tok".into()),
        max_upload_bytes: 1000,
        ..test_config()
    };
    let s = start_with(config, SimBackend::with_two_models(RATE_HZ)).await;
    let paths = [
        "/api/models/a.onnx/load",
        "/api/models/a.onnx/activate",
        "/api/models/a.onnx/unload",
        "/api/experiment/stop",
    ];
    for path in paths {
        for h in [&[][..], &[("authorization", "Bearer nope")]] {
            let (code, e) = http_json(&s, "POST", path, h, vec![]).await;
            assert_eq!(code, 401, "{path} {h:?}: {e}");
        }
    }
    let (code, _) = http_json(
        &s,
        "POST",
        "/api/experiment/start",
        &[],
        br#"{"kind":"shadow"}"#.to_vec(),
    )
    .await;
    assert_eq!(code, 401);
    assert!(s.backend.swaps().is_empty() && s.backend.last_experiment().is_none());
    // Reads that show live data or provenance need the token too; /metrics unless opened.
    for path in [
        "/api/status",
        "/api/models",
        "/api/models/active",
        "/metrics",
    ] {
        for h in [&[][..], &[("authorization", "Bearer nope")]] {
            let (code, e) = http_json(&s, "GET", path, h, vec![]).await;
            assert_eq!(code, 401, "GET {path} {h:?}: {e}");
        }
    }
    let auth = ("authorization", "Bearer tok");
    let (_, st) = http_json(&s, "GET", "/api/status", &[auth], vec![]).await;
    assert_eq!(st["server"]["token_required"], true);
    assert_eq!(st["server"]["max_upload_bytes"], 1000);
    // The page's own files stay open (it must load to read its token).
    let (code, _, _) = http(&s, "GET", "/", &[], vec![]).await;
    assert_ne!(code, 401);

    let (code, e) = http_json(
        &s,
        "POST",
        "/api/models/a.onnx/activate",
        &[auth, ("origin", "https://evil.example")],
        vec![],
    )
    .await;
    assert_eq!(code, 403, "{e}");
    let same_origin = format!("http://{}", s.http);
    let (code, e) = http_json(
        &s,
        "POST",
        "/api/models/a.onnx/activate",
        &[auth, ("origin", &same_origin)],
        vec![],
    )
    .await;
    assert_eq!(code, 200, "{e}");

    let (code, e) = http_json(
        &s,
        "POST",
        "/api/models/big.onnx/load",
        &[auth],
        vec![b' '; 1001],
    )
    .await;
    assert_eq!(code, 413, "{e}");
    assert!(
        e["error"].as_str().unwrap().contains("limit of 1000 bytes"),
        "{e}"
    );
    let (code, e) = http_json(
        &s,
        "POST",
        "/api/models/big.onnx/load",
        &[auth],
        vec![b' '; 100_000],
    )
    .await;
    assert_eq!(code, 413, "{e}");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_open_with_the_flag_only() {
    let config = Config {
        token: Some("tok".into()),
        metrics_open: true,
        ..test_config()
    };
    let s = start_with(config, SimBackend::with_two_models(RATE_HZ)).await;
    let (code, _, _) = http(&s, "GET", "/metrics", &[], vec![]).await;
    assert_eq!(code, 200, "--open-metrics");
    let (code, _) = http_json(&s, "GET", "/api/status", &[], vec![]).await;
    assert_eq!(code, 401, "the rest stays closed");
    s.stop().await;
}

/// A strict reader of the Prometheus text format: every sample belongs to a family declared
/// with HELP and TYPE before it, names and labels are well-formed, values are numbers.
type Sample = (String, Vec<(String, String)>, f64);

fn parse_prometheus(text: &str) -> Vec<Sample> {
    let name_ok = |n: &str| {
        !n.is_empty()
            && n.chars().enumerate().all(|(i, c)| {
                c.is_ascii_alphabetic() || c == '_' || c == ':' || (i > 0 && c.is_ascii_digit())
            })
    };
    let mut types = std::collections::HashMap::new();
    let mut helps = std::collections::HashSet::new();
    let mut samples = Vec::new();
    for line in text.lines() {
        if let Some(rest) = line.strip_prefix("# HELP ") {
            let name = rest.split(' ').next().unwrap();
            assert!(
                name_ok(name) && helps.insert(name.to_string()),
                "HELP once: {line}"
            );
        } else if let Some(rest) = line.strip_prefix("# TYPE ") {
            let (name, kind) = rest.split_once(' ').unwrap();
            assert!(
                ["gauge", "counter", "summary", "histogram", "untyped"].contains(&kind),
                "{line}"
            );
            assert!(
                types.insert(name.to_string(), kind.to_string()).is_none(),
                "TYPE once: {line}"
            );
        } else {
            assert!(!line.starts_with('#') && !line.is_empty(), "{line:?}");
            let (series, value) = line.rsplit_once(' ').unwrap();
            let value: f64 = match value {
                "NaN" => f64::NAN,
                "+Inf" => f64::INFINITY,
                "-Inf" => f64::NEG_INFINITY,
                v => v.parse().unwrap_or_else(|_| panic!("value of {line}")),
            };
            let (name, labels) = match series.split_once('{') {
                None => (series, vec![]),
                Some((name, rest)) => {
                    let body = rest.strip_suffix('}').unwrap_or_else(|| panic!("{line}"));
                    let labels = body
                        .split("\",")
                        .map(|kv| {
                            let (k, v) = kv.split_once("=\"").unwrap_or_else(|| panic!("{line}"));
                            assert!(name_ok(k), "{line}");
                            (k.to_string(), v.trim_end_matches('"').to_string())
                        })
                        .collect();
                    (name, labels)
                }
            };
            assert!(name_ok(name), "{line}");
            let kind = types
                .get(name)
                .unwrap_or_else(|| panic!("no TYPE before {line}"));
            assert!(helps.contains(name));
            if kind == "counter" {
                assert!(name.ends_with("_total") && value >= 0.0, "{line}");
            }
            samples.push((name.to_string(), labels, value));
        }
    }
    samples
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_parse_and_tell_the_truth() {
    let s = start().await;
    http_json(&s, "POST", "/api/models/a.onnx/activate", &[], vec![]).await;
    tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    let (code, ctype, body) = http(&s, "GET", "/metrics", &[], vec![]).await;
    assert_eq!(code, 200);
    assert!(ctype.starts_with("text/plain; version=0.0.4"), "{ctype}");
    let text = String::from_utf8(body).unwrap();
    let samples = parse_prometheus(&text);
    let get = |name: &str, label: Option<(&str, &str)>| {
        samples
            .iter()
            .find(|(n, l, _)| {
                n == name && label.is_none_or(|(k, v)| l.iter().any(|(a, b)| a == k && b == v))
            })
            .unwrap_or_else(|| panic!("{name} {label:?} in\n{text}"))
            .2
    };
    assert_eq!(get("haptics_loop_alive", None), 1.0);
    assert!(get("haptics_loop_steps_total", None) > 0.0);
    assert_eq!(get("haptics_loop_rate_hz", None), RATE_HZ);
    assert_eq!(
        get("haptics_active_model_info", Some(("name", "a.onnx"))),
        1.0
    );
    assert_eq!(get("haptics_models", Some(("state", "active"))), 1.0);
    assert_eq!(get("haptics_models", Some(("state", "available"))), 1.0);
    assert_eq!(
        get("haptics_round_trip_latency_us", Some(("quantile", "0.99"))),
        14.0
    );
    assert!(get("haptics_control_requests_ok_total", None) >= 1.0);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_or_how_to_build_it() {
    let s = start().await;
    let (code, ctype, body) = http(&s, "GET", "/", &[], vec![]).await;
    assert_eq!(code, 200);
    assert!(ctype.starts_with("text/html"), "{ctype}");
    let html = String::from_utf8(body).unwrap();
    if control_plane::http::assets::page_is_embedded() {
        assert!(!html.contains("was not built"));
    } else {
        assert!(html.contains("npm run build"), "{html}");
    }
    let (code, _, _) = http(&s, "GET", "/assets/does-not-exist.js", &[], vec![]).await;
    assert_eq!(code, 404);
    let _: Value = http_json(&s, "GET", "/api/models", &[], vec![]).await.1;
    s.stop().await;
}
