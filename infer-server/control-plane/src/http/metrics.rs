//! `/metrics` in the Prometheus text format (version 0.0.4).
use std::fmt::Write as _;

use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};

use crate::backend::{Latency, ModelState};
use crate::core::Core;
use crate::error::ControlError;
use crate::stats::Stats;

pub async fn metrics(
    State(core): State<Core>,
    headers: axum::http::HeaderMap,
) -> Result<Response, ControlError> {
    if !core.config.metrics_open {
        super::api::authorize_read(&core, &headers)?;
    }
    let status = core.status().await?;
    let models = core.list_models().await.unwrap_or_default();
    let mut m = Metrics::default();
    let l = &status.loop_status;
    m.gauge(
        "haptics_loop_alive",
        "1 when an rt-loop is attached and its heartbeat is fresh",
        &[],
        bool_f(l.alive),
    );
    m.gauge(
        "haptics_recorder_failed",
        "1 when the current or last run's recording failed (rows lost; /api/status says why)",
        &[],
        bool_f(l.recorder_failed()),
    );
    m.counter(
        "haptics_loop_steps_total",
        "Steps of the loop's current (or last) run; it restarts at 0 with every run",
        l.step as f64,
    );
    m.gauge(
        "haptics_loop_rate_hz",
        "Loop steps per second over the last second",
        &[],
        l.rate_hz,
    );
    m.counter(
        "haptics_loop_fallbacks_total",
        "Steps rendered with the fallback model",
        l.fallbacks as f64,
    );
    for (level, n) in [
        ("on_time", l.on_time),
        ("late_one", l.late_one),
        ("held", l.held),
        ("fallback", l.fallback),
    ] {
        m.counter_with(
            "haptics_steps_total",
            "Steps of the current (or last) run by the rung of the degradation ladder that rendered them",
            &[("level", level)],
            n as f64,
        );
    }
    m.counter(
        "haptics_steps_saturated_total",
        "Steps of the current (or last) run rendered at the force limit because the model answered above it",
        l.saturated as f64,
    );
    m.counter(
        "haptics_ring_corrupt_total",
        "Ring slots or indices the loop found corrupt",
        l.corrupt as f64,
    );
    m.gauge(
        "haptics_max_transition_step_newtons",
        "Largest one-step change of the rendered force caused by a ladder transition",
        &[],
        l.max_transition_step_n,
    );
    let p = &l.passivity;
    m.gauge(
        "haptics_passivity_on",
        "Whether the passivity layer's damper acts (1) or only observes (0)",
        &[],
        f64::from(u8::from(p.on)),
    );
    for (dir, v) in [
        ("held", p.energy_j),
        ("received", p.received_j),
        ("returned", p.returned_j),
    ] {
        m.gauge(
            "haptics_passivity_energy_joules",
            "Energy of the rendered object by the passivity observer: held (received - returned, less forgotten), received from and returned to the hand",
            &[("kind", dir)],
            v,
        );
    }
    m.gauge(
        "haptics_passivity_damping_newton_seconds_per_metre",
        "Largest damping the passivity layer applied this run",
        &[],
        p.damping_ns_per_m,
    );
    m.counter(
        "haptics_passivity_active_steps_total",
        "Steps on which the passivity layer changed the rendered force",
        p.active_steps as f64,
    );
    m.counter(
        "haptics_board_faults_total",
        "Board failures that ended a run (failed read, DAC write or watchdog kick, board gone, watchdog tripped); each put the motor at 0 A",
        l.board_faults as f64,
    );
    m.counter(
        "haptics_board_fifo_overflows_total",
        "Encoder snapshots the board's FIFO lost in the current (or last) run (counted, not fatal)",
        l.board_fifo_overflows as f64,
    );
    m.counter(
        "haptics_board_quadrature_errors_total",
        "Encoder snapshots flagged with a quadrature error in the current (or last) run (counted, not fatal)",
        l.board_quadrature_errors as f64,
    );
    m.counter(
        "haptics_loop_deadline_misses_total",
        "Steps that missed their deadline",
        l.deadline_misses as f64,
    );
    m.counter(
        "haptics_loop_overruns_total",
        "Realtime steps that ended after the next period began",
        l.overruns as f64,
    );
    m.counter(
        "haptics_loop_telemetry_drops_total",
        "Telemetry samples the loop could not publish",
        l.telemetry_drops as f64,
    );
    m.gauge(
        "haptics_experiment_running",
        "1 while an experiment runs",
        &[("kind", l.experiment.kind.as_str())],
        bool_f(l.experiment.running),
    );
    m.latency(
        "haptics_round_trip_latency_us",
        "Features to force round trip as the loop sees it, microseconds",
        &l.round_trip_latency,
    );
    m.latency(
        "haptics_period_jitter_us",
        "Loop period minus its nominal value (absolute), microseconds",
        &l.period_jitter,
    );
    m.latency(
        "haptics_inference_latency_us",
        "Ring to ring inference latency measured by the server, microseconds",
        &status.server.inference_latency,
    );
    m.counter(
        "haptics_predictions_total",
        "Forces the server predicted",
        status.server.predictions as f64,
    );
    m.gauge(
        "haptics_server_uptime_seconds",
        "Seconds since infer-server started",
        &[],
        status.server.uptime_s,
    );
    if let Some(a) = &status.active_model {
        m.gauge(
            "haptics_active_model_info",
            "The active model (value 1)",
            &[
                ("name", a.name.as_str()),
                ("kind", a.kind.as_str()),
                ("model_id", &a.model_id.to_string()),
            ],
            1.0,
        );
    }
    for state in [
        ModelState::Available,
        ModelState::Loaded,
        ModelState::Active,
        ModelState::Failed,
    ] {
        let n = models.iter().filter(|m| m.state == state).count();
        m.gauge(
            "haptics_models",
            "Models by state",
            &[("state", state.as_str())],
            n as f64,
        );
    }
    let s = &core.stats;
    m.gauge(
        "haptics_control_ws_clients",
        "Open telemetry WebSockets",
        &[],
        Stats::get(&s.ws_clients) as f64,
    );
    m.counter(
        "haptics_control_ws_frames_total",
        "Binary telemetry frames sent",
        Stats::get(&s.ws_frames) as f64,
    );
    m.counter(
        "haptics_control_ws_bytes_total",
        "Bytes of binary telemetry frames sent",
        Stats::get(&s.ws_bytes) as f64,
    );
    m.gauge(
        "haptics_control_grpc_streams",
        "Open gRPC telemetry streams",
        &[],
        Stats::get(&s.grpc_streams) as f64,
    );
    m.counter(
        "haptics_control_grpc_samples_total",
        "Telemetry samples sent over gRPC",
        Stats::get(&s.grpc_samples) as f64,
    );
    m.counter(
        "haptics_control_lagged_batches_total",
        "Telemetry batches slow clients missed",
        Stats::get(&s.lagged_batches) as f64,
    );
    m.counter(
        "haptics_control_requests_ok_total",
        "Control plane calls that succeeded",
        Stats::get(&s.requests_ok) as f64,
    );
    m.counter(
        "haptics_control_requests_failed_total",
        "Control plane calls that failed",
        Stats::get(&s.requests_failed) as f64,
    );
    for (reason, counter) in [
        ("too_large", &s.uploads_refused_too_large),
        ("invalid", &s.uploads_refused_invalid),
    ] {
        m.counter_with(
            "haptics_model_uploads_refused_total",
            "Model uploads refused: over the size limit (too_large) or not a valid model (invalid)",
            &[("reason", reason)],
            Stats::get(counter) as f64,
        );
    }
    Ok((
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        m.text,
    )
        .into_response())
}

fn bool_f(b: bool) -> f64 {
    if b {
        1.0
    } else {
        0.0
    }
}

/// Writes families with HELP and TYPE once each (families may get several samples).
#[derive(Default)]
struct Metrics {
    text: String,
    declared: Vec<&'static str>,
}

impl Metrics {
    fn declare(&mut self, name: &'static str, help: &str, kind: &str) {
        if !self.declared.contains(&name) {
            self.declared.push(name);
            let _ = writeln!(self.text, "# HELP {name} {help}");
            let _ = writeln!(self.text, "# TYPE {name} {kind}");
        }
    }

    fn sample(&mut self, name: &str, labels: &[(&str, &str)], value: f64) {
        self.text.push_str(name);
        if !labels.is_empty() {
            self.text.push('{');
            for (i, (k, v)) in labels.iter().enumerate() {
                if i > 0 {
                    self.text.push(',');
                }
                let _ = write!(self.text, "{k}=\"{}\"", escape(v));
            }
            self.text.push('}');
        }
        let _ = writeln!(self.text, " {}", number(value));
    }

    fn gauge(&mut self, name: &'static str, help: &str, labels: &[(&str, &str)], value: f64) {
        self.declare(name, help, "gauge");
        self.sample(name, labels, value);
    }

    fn counter(&mut self, name: &'static str, help: &str, value: f64) {
        self.counter_with(name, help, &[], value);
    }

    fn counter_with(
        &mut self,
        name: &'static str,
        help: &str,
        labels: &[(&str, &str)],
        value: f64,
    ) {
        self.declare(name, help, "counter");
        self.sample(name, labels, value);
    }

    fn latency(&mut self, name: &'static str, help: &str, l: &Latency) {
        self.declare(name, help, "gauge");
        for (q, v) in [
            ("0.5", l.p50_us),
            ("0.99", l.p99_us),
            ("0.999", l.p999_us),
            ("1", l.max_us),
        ] {
            self.sample(name, &[("quantile", q)], v);
        }
    }
}

fn number(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else if v.is_infinite() {
        if v > 0.0 { "+Inf" } else { "-Inf" }.into()
    } else {
        format!("{v}")
    }
}

fn escape(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}
