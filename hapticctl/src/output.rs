//! Human-readable and JSON renderings of the control plane's messages.
use haptics_proto::grpc as pb;
use serde_json::{json, Value};

pub fn state_name(m: &pb::ModelInfo) -> &'static str {
    match m.state() {
        pb::ModelState::Unspecified => "unknown",
        pb::ModelState::Available => "available",
        pb::ModelState::Loaded => "loaded",
        pb::ModelState::Active => "active",
        pb::ModelState::Failed => "failed",
    }
}

pub fn model_json(m: &pb::ModelInfo) -> Value {
    json!({
        "name": m.name,
        "state": state_name(m),
        "kind": m.kind,
        "features": m.features,
        "units": m.units,
        "error": (!m.error.is_empty()).then_some(&m.error),
        "size_bytes": m.size_bytes,
        "model_id": m.model_id,
        "active_since_step": (m.state() == pb::ModelState::Active).then_some(m.active_since_step),
        "provenance": serde_json::from_str::<Value>(&m.provenance_json).unwrap_or(Value::Null),
        "cost": serde_json::from_str::<Value>(&m.cost_json).unwrap_or(Value::Null),
        "reference_steps": m.reference_steps,
    })
}

/// What one call costs, in a few characters: the export's p50/p99 (measured on the exporting
/// machine, `haptics.cost`) and this server's warm-up median, us; `-` for what is unknown
/// (a model not loaded, or exported without the measurement).
pub fn cost_cell(m: &pb::ModelInfo) -> String {
    let cost = serde_json::from_str::<Value>(&m.cost_json).unwrap_or(Value::Null);
    let us = |part: &str, key: &str| cost[part][key].as_f64().map(|v| format!("{v:.1}"));
    let export = match (us("export", "p50_us"), us("export", "p99_us")) {
        (Some(a), Some(b)) => format!("{a}/{b}"),
        _ => "-".into(),
    };
    match us("warmup", "p50_us") {
        Some(w) => format!("{export} (here {w})"),
        None if export == "-" => "-".into(),
        None => export,
    }
}

/// Whether this server computed the model's reference steps as its export did: `32 steps`
/// (every one agreed: it would have refused the model otherwise), `none` (loaded, but the
/// model carries none: nothing was compared), `-` (not loaded).
pub fn checked_cell(m: &pb::ModelInfo) -> String {
    let loaded = matches!(m.state(), pb::ModelState::Loaded | pb::ModelState::Active);
    match (loaded, m.reference_steps) {
        (false, _) => "-".into(),
        (true, 0) => "none".into(),
        (true, n) => format!("{n} steps"),
    }
}

pub fn models_table(models: &[pb::ModelInfo]) -> String {
    if models.is_empty() {
        return "no models in the model directory (load one with `hapticctl load --file PATH`)\n"
            .into();
    }
    let width = models
        .iter()
        .map(|m| m.name.len())
        .max()
        .unwrap_or(4)
        .max(4);
    let mut out = format!(
        "{:<width$}  {:<9}  {:<9}  {:>9}  {:<22}  {:<9}  FEATURES\n",
        "NAME", "STATE", "KIND", "SIZE", "COST us p50/p99", "REFERENCE"
    );
    for m in models {
        let mut line = format!(
            "{:<width$}  {:<9}  {:<9}  {:>9}  {:<22}  {:<9}  {}",
            m.name,
            state_name(m),
            if m.kind.is_empty() { "-" } else { &m.kind },
            human_bytes(m.size_bytes),
            cost_cell(m),
            checked_cell(m),
            if m.features.is_empty() {
                "-".to_string()
            } else {
                m.features.join(",")
            },
        );
        if m.state() == pb::ModelState::Active {
            line.push_str(&format!(
                "  (since feature message {})",
                m.active_since_step
            ));
        }
        if !m.error.is_empty() {
            line.push_str(&format!("  error: {}", m.error));
        }
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out
}

pub fn model_line(m: &pb::ModelInfo) -> String {
    format!(
        "{} ({}, {}, features: {}, id {})",
        m.name,
        state_name(m),
        if m.kind.is_empty() {
            "kind unknown"
        } else {
            &m.kind
        },
        m.features.join(", "),
        m.model_id
    )
}

fn human_bytes(n: u64) -> String {
    if n >= 1 << 20 {
        format!("{:.1} MiB", n as f64 / f64::from(1 << 20))
    } else if n >= 1 << 10 {
        format!("{:.1} KiB", n as f64 / 1024.0)
    } else {
        format!("{n} B")
    }
}

fn latency_json(l: Option<&pb::LatencyPercentiles>) -> Value {
    let l = l.cloned().unwrap_or_default();
    json!({ "p50_us": l.p50_us, "p99_us": l.p99_us, "p999_us": l.p999_us, "max_us": l.max_us, "count": l.count })
}

fn passivity_json(p: Option<&pb::PassivityStatus>) -> Value {
    let p = p.copied().unwrap_or_default();
    json!({ "on": p.on, "energy_j": p.energy_j, "received_j": p.received_j, "returned_j": p.returned_j,
            "damping_ns_per_m": p.damping_ns_per_m, "active_steps": p.active_steps })
}

pub fn status_json(s: &pb::Status) -> Value {
    let e = s.experiment.clone().unwrap_or_default();
    json!({
        "loop": {
            "alive": s.loop_alive,
            "mode": s.mode,
            "clock": s.clock,
            "board": s.board,
            "rate_hz": s.rate_hz,
            "step": s.step,
            "fallbacks": s.fallbacks,
            "deadline_misses": s.deadline_misses,
            "on_time": s.on_time,
            "late_one": s.late_one,
            "held": s.held,
            "fallback": s.fallback,
            "corrupt": s.corrupt,
            "max_transition_step_n": s.max_transition_step_n,
            "saturated": s.saturated,
            "board_faults": s.board_faults,
            "board_fault": s.board_fault,
            "board_fifo_overflows": s.board_fifo_overflows,
            "board_quadrature_errors": s.board_quadrature_errors,
            "scheduling": s.scheduling,
            "recorder": s.recorder,
            "recorder_failed": s.recorder_failed,
            "telemetry_drops": s.telemetry_drops,
            "experiment": { "kind": e.kind, "running": e.running, "cycle": e.cycle, "phase": e.phase },
            "round_trip_latency": latency_json(s.round_trip_latency.as_ref()),
            "overruns": s.overruns,
            "period_jitter": latency_json(s.period_jitter.as_ref()),
            "passivity": passivity_json(s.passivity.as_ref()),
        },
        "server": {
            "version": s.server_version,
            "uptime_s": s.uptime_s,
            "predictions": s.predictions,
            "inference_latency": latency_json(s.inference_latency.as_ref()),
            "token_required": s.token_required,
            "max_upload_bytes": s.max_upload_bytes,
        },
        "active_model": s.active_model.as_ref().map(model_json),
    })
}

pub fn status_text(s: &pb::Status) -> String {
    let mut out = String::new();
    let lat = |l: Option<&pb::LatencyPercentiles>| match l {
        Some(l) if l.count > 0 => format!(
            "p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us ({} samples)",
            l.p50_us, l.p99_us, l.p999_us, l.max_us, l.count
        ),
        _ => "no samples".into(),
    };
    if s.loop_alive {
        out.push_str(&format!(
            "loop:        running, {} clock, {} board, {:.1} Hz, step {} of the run\n",
            s.clock, s.board, s.rate_hz, s.step
        ));
    } else {
        out.push_str("loop:        not attached (no rt-loop, or its heartbeat stopped)\n");
    }
    let e = s.experiment.clone().unwrap_or_default();
    if e.running {
        out.push_str(&format!(
            "experiment:  {} (cycle {}, {})\n",
            e.kind, e.cycle, e.phase
        ));
    } else {
        out.push_str("experiment:  idle\n");
    }
    match &s.active_model {
        Some(m) => out.push_str(&format!(
            "model:       {} ({}, {})\n",
            m.name,
            if m.kind.is_empty() {
                "kind unknown"
            } else {
                &m.kind
            },
            // A step of a loop that is gone would be stale: say what holds now.
            if s.loop_alive {
                format!("since step {}", m.active_since_step)
            } else {
                "waiting for a loop".to_string()
            }
        )),
        None => out.push_str("model:       none (the loop renders its fallback)\n"),
    }
    out.push_str(&format!(
        "fallbacks:   {}    deadline misses: {}    telemetry drops: {}\n",
        s.fallbacks, s.deadline_misses, s.telemetry_drops
    ));
    out.push_str(&format!(
        "ladder:      on time {}    late one {}    held {}    fallback {}    saturated {}    max transition step {:.4} N    corrupt {}\n",
        s.on_time, s.late_one, s.held, s.fallback, s.saturated, s.max_transition_step_n, s.corrupt
    ));
    if s.board_faults > 0 || s.board_fifo_overflows > 0 || s.board_quadrature_errors > 0 {
        out.push_str(&format!(
            "board:       {} fault(s) (each at 0 A), last: {}    FIFO overflows {}    quadrature errors {}\n",
            s.board_faults,
            if s.board_fault.is_empty() { "-" } else { &s.board_fault },
            s.board_fifo_overflows,
            s.board_quadrature_errors
        ));
    }
    let p = s.passivity.unwrap_or_default();
    out.push_str(&format!(
        "passivity:   {}    energy {:.4} J (received {:.4} J, returned {:.4} J)    max damping {:.1} N s/m    active steps {}\n",
        if p.on { "on" } else { "off (observing)" },
        p.energy_j, p.received_j, p.returned_j, p.damping_ns_per_m, p.active_steps
    ));
    out.push_str(&format!(
        "round trip:  {}\n",
        lat(s.round_trip_latency.as_ref())
    ));
    out.push_str(&format!(
        "inference:   {}\n",
        lat(s.inference_latency.as_ref())
    ));
    out.push_str(&format!(
        "jitter:      {}    overruns: {}\n",
        lat(s.period_jitter.as_ref()),
        s.overruns
    ));
    out.push_str(&format!("scheduling:  {}\n", or_dash(&s.scheduling)));
    out.push_str(&format!(
        "recorder:    {}{}\n",
        if s.recorder_failed {
            "RECORDER ERROR: "
        } else {
            ""
        },
        or_dash(&s.recorder)
    ));
    out.push_str(&format!(
        "server:      {} up {:.0} s, {} predictions{}\n",
        or_dash(&s.server_version),
        s.uptime_s,
        s.predictions,
        if s.token_required {
            ", token required for changes"
        } else {
            ""
        }
    ));
    out
}

fn or_dash(s: &str) -> &str {
    if s.is_empty() {
        "-"
    } else {
        s
    }
}

pub fn sample_json(x: &pb::TelemetrySample) -> Value {
    let num = |v: f64| if v.is_finite() { json!(v) } else { Value::Null };
    json!({
        "step": x.step,
        "time_s": x.time_s,
        "steps": x.steps,
        "f_ref": num(x.f_ref),
        "f_res_min": num(x.f_res_min),
        "f_res_max": num(x.f_res_max),
        "f_pred": num(x.f_pred),
        "position_x": num(x.position_x),
        "velocity": num(x.velocity),
        "acceleration": num(x.acceleration),
        "f_true": num(x.f_true),
        "f_object": num(x.f_object),
        "fallbacks": x.fallbacks,
        "min": x.min.iter().map(|v| num(*v)).collect::<Vec<_>>(),
        "max": x.max.iter().map(|v| num(*v)).collect::<Vec<_>>(),
    })
}

/// Said once under the first sample whose F_pred is NaN: no model predicts in that run.
pub const F_PRED_NAN: &str = "F_pred is NaN while no model predicts: abstraction and \
    position-replay runs measure the object (F_res) without asking the model; shadow and \
    reproduction runs show its prediction";

pub const SAMPLE_HEADER: &str =
    "      step    time_s     F_ref  F_res[min      max]    F_pred   x [mm]  v [mm/s]  fallbacks";

pub fn sample_line(x: &pb::TelemetrySample) -> String {
    format!(
        "{:>10} {:>9.4} {:>9.3} {:>9.3} {:>8.3} {:>9.3} {:>8.3} {:>9.2} {:>10}",
        x.step,
        x.time_s,
        x.f_ref,
        x.f_res_min,
        x.f_res_max,
        x.f_pred,
        x.position_x * 1e3,
        x.velocity * 1e3,
        x.fallbacks
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with_cost(cost: &str) -> pb::ModelInfo {
        pb::ModelInfo {
            name: "m".into(),
            cost_json: cost.into(),
            ..Default::default()
        }
    }

    #[test]
    fn cost_cell_shows_the_export_and_the_warm_up() {
        let both = r#"{"export":{"p50_us":3.14,"p99_us":9.0},"warmup":{"p50_us":2.5}}"#;
        assert_eq!(cost_cell(&with_cost(both)), "3.1/9.0 (here 2.5)");
        let warm_only = r#"{"export":null,"warmup":{"p50_us":2.5}}"#;
        assert_eq!(cost_cell(&with_cost(warm_only)), "- (here 2.5)");
        assert_eq!(cost_cell(&with_cost("")), "-");
        assert_eq!(
            model_json(&with_cost(both))["cost"]["export"]["p99_us"],
            9.0
        );
    }

    /// `REFERENCE`: the steps checked where the model is loaded; `none` where it carries none
    /// (nothing compared, said so rather than left blank); `-` where it is not loaded.
    #[test]
    fn the_reference_cell_says_what_was_checked() {
        let with = |state: pb::ModelState, steps: u32| pb::ModelInfo {
            name: "m".into(),
            state: state as i32,
            reference_steps: steps,
            ..Default::default()
        };
        assert_eq!(checked_cell(&with(pb::ModelState::Active, 32)), "32 steps");
        assert_eq!(checked_cell(&with(pb::ModelState::Loaded, 0)), "none");
        assert_eq!(checked_cell(&with(pb::ModelState::Available, 0)), "-");
        assert_eq!(checked_cell(&with(pb::ModelState::Failed, 0)), "-");
        assert_eq!(
            model_json(&with(pb::ModelState::Active, 32))["reference_steps"],
            32
        );
        let table = models_table(&[with(pb::ModelState::Active, 32)]);
        assert!(
            table.lines().next().unwrap().contains("REFERENCE"),
            "{table}"
        );
        assert!(table.contains("32 steps"), "{table}");
    }
}
