//! The `haptics.v1` gRPC services over `Core`.
use std::pin::Pin;

use tokio::sync::{broadcast, mpsc};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status};

use crate::backend::{ExperimentRequest, Latency, ModelInfo, ModelState, StatusSnapshot};
use crate::core::Core;
use crate::pb;
use crate::stats::{GaugeGuard, Stats};
use crate::telemetry::{Bucket, Decimator};

/// Decimation used when a client asks for 0.
pub const DEFAULT_DECIMATION: u32 = 100;

pub struct ModelSvc {
    core: Core,
}

pub struct LoopSvc {
    core: Core,
}

impl ModelSvc {
    pub fn new(core: Core) -> Self {
        Self { core }
    }
}

impl LoopSvc {
    pub fn new(core: Core) -> Self {
        Self { core }
    }
}

#[tonic::async_trait]
impl pb::model_service_server::ModelService for ModelSvc {
    async fn list_models(
        &self,
        request: Request<pb::ListModelsRequest>,
    ) -> Result<Response<pb::ListModelsResponse>, Status> {
        self.core.auth.check_grpc(&request)?;
        let models = self.core.list_models().await?;
        Ok(Response::new(pb::ListModelsResponse {
            models: models.iter().map(model_to_pb).collect(),
        }))
    }

    async fn load_model(
        &self,
        request: Request<pb::LoadModelRequest>,
    ) -> Result<Response<pb::LoadModelResponse>, Status> {
        self.core.auth.check_grpc(&request)?;
        let r = request.into_inner();
        let upload = (!r.onnx.is_empty()).then_some(r.onnx);
        let model = self.core.load_model(r.name, upload).await?;
        Ok(Response::new(pb::LoadModelResponse {
            model: Some(model_to_pb(&model)),
        }))
    }

    async fn activate_model(
        &self,
        request: Request<pb::ActivateModelRequest>,
    ) -> Result<Response<pb::ActivateModelResponse>, Status> {
        self.core.auth.check_grpc(&request)?;
        let r = request.into_inner();
        let a = self.core.activate_model(r.name, r.load_if_needed).await?;
        Ok(Response::new(pb::ActivateModelResponse {
            model: Some(model_to_pb(&a.model)),
            effective_step: a.effective_step,
            warnings: a.warnings,
        }))
    }

    async fn unload_model(
        &self,
        request: Request<pb::UnloadModelRequest>,
    ) -> Result<Response<pb::UnloadModelResponse>, Status> {
        self.core.auth.check_grpc(&request)?;
        self.core.unload_model(request.into_inner().name).await?;
        Ok(Response::new(pb::UnloadModelResponse {}))
    }

    async fn get_active_model(
        &self,
        request: Request<pb::GetActiveModelRequest>,
    ) -> Result<Response<pb::ModelInfo>, Status> {
        self.core.auth.check_grpc(&request)?;
        match self.core.active_model().await? {
            Some(m) => Ok(Response::new(model_to_pb(&m))),
            None => Err(Status::not_found(
                "no model is active: the loop runs on its fallback",
            )),
        }
    }
}

type SampleStream =
    Pin<Box<dyn tokio_stream::Stream<Item = Result<pb::TelemetrySample, Status>> + Send>>;

#[tonic::async_trait]
impl pb::loop_service_server::LoopService for LoopSvc {
    async fn get_status(
        &self,
        request: Request<pb::GetStatusRequest>,
    ) -> Result<Response<pb::Status>, Status> {
        self.core.auth.check_grpc(&request)?;
        let s = self.core.status().await?;
        Ok(Response::new(status_to_pb(
            &s,
            self.core.auth.required(),
            self.core.config.max_upload_bytes,
        )))
    }

    async fn start_experiment(
        &self,
        request: Request<pb::StartExperimentRequest>,
    ) -> Result<Response<pb::StartExperimentResponse>, Status> {
        self.core.auth.check_grpc(&request)?;
        let r = request.into_inner();
        let req =
            ExperimentRequest::new(&r.kind, r.ramp_rate, r.cycles, r.f_max_start, r.f_max_step)?;
        self.core.start_experiment(req).await?;
        Ok(Response::new(pb::StartExperimentResponse {}))
    }

    async fn stop_experiment(
        &self,
        request: Request<pb::StopExperimentRequest>,
    ) -> Result<Response<pb::StopExperimentResponse>, Status> {
        self.core.auth.check_grpc(&request)?;
        self.core.stop_experiment().await?;
        Ok(Response::new(pb::StopExperimentResponse {}))
    }

    type StreamTelemetryStream = SampleStream;

    async fn stream_telemetry(
        &self,
        request: Request<pb::StreamTelemetryRequest>,
    ) -> Result<Response<Self::StreamTelemetryStream>, Status> {
        self.core.auth.check_grpc(&request)?;
        let decimation = match request.into_inner().decimation {
            0 => DEFAULT_DECIMATION,
            d => d,
        };
        let (tx, rx) = mpsc::channel(256);
        let core = self.core.clone();
        let telemetry = core.backend.subscribe_telemetry();
        tokio::spawn(pump_samples(core, telemetry, decimation, tx));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }
}

/// Decimates the backend's batches for one client until the client goes away or the server
/// shuts down; dropping `tx` then ends the stream cleanly (status OK).
async fn pump_samples(
    core: Core,
    mut telemetry: broadcast::Receiver<crate::telemetry::TelemetryBatch>,
    decimation: u32,
    tx: mpsc::Sender<Result<pb::TelemetrySample, Status>>,
) {
    let stats = &core.stats;
    let _open = GaugeGuard::new(&stats.grpc_streams);
    let mut decimator = Decimator::new(decimation);
    let mut out = Vec::new();
    loop {
        let batch = tokio::select! {
            _ = core.shutdown.wait() => return,
            _ = tx.closed() => return,
            batch = telemetry.recv() => batch,
        };
        let batch = match batch {
            Ok(batch) => batch,
            Err(broadcast::error::RecvError::Lagged(n)) => {
                Stats::add(&stats.lagged_batches, n);
                continue;
            }
            Err(broadcast::error::RecvError::Closed) => return,
        };
        out.clear();
        for bucket in batch.iter() {
            decimator.push(bucket, &mut out);
        }
        for bucket in &out {
            let sent = tokio::select! {
                _ = core.shutdown.wait() => return,
                sent = tx.send(Ok(sample_to_pb(bucket))) => sent,
            };
            if sent.is_err() {
                return;
            }
            Stats::add(&stats.grpc_samples, 1);
        }
    }
}

pub fn sample_to_pb(b: &Bucket) -> pb::TelemetrySample {
    use crate::telemetry::series::*;
    pb::TelemetrySample {
        step: b.first_step,
        time_s: b.time_s,
        f_ref: b.last[F_REF],
        f_res_min: b.min[RTOB_FORCE],
        f_res_max: b.max[RTOB_FORCE],
        f_pred: b.last[F_PRED],
        position_x: b.last[POSITION_X],
        velocity: b.last[VELOCITY],
        acceleration: b.last[ACCELERATION],
        f_true: b.last[F_TRUE],
        fallback: b.fallbacks > 0,
        steps: b.steps,
        fallbacks: b.fallbacks,
        min: b.min[..N_SERIES].to_vec(),
        max: b.max[..N_SERIES].to_vec(),
        f_object: b.last[F_OBJECT],
    }
}

pub fn model_state_to_pb(s: ModelState) -> pb::ModelState {
    match s {
        ModelState::Available => pb::ModelState::Available,
        ModelState::Loaded => pb::ModelState::Loaded,
        ModelState::Active => pb::ModelState::Active,
        ModelState::Failed => pb::ModelState::Failed,
    }
}

pub fn model_to_pb(m: &ModelInfo) -> pb::ModelInfo {
    pb::ModelInfo {
        name: m.name.clone(),
        state: model_state_to_pb(m.state) as i32,
        kind: m.kind.clone(),
        features: m.features.clone(),
        units: m.units.clone(),
        provenance_json: m.provenance_json.clone(),
        error: m.error.clone().unwrap_or_default(),
        size_bytes: m.size_bytes,
        model_id: m.model_id,
        active_since_step: m.active_since_step.unwrap_or(0),
        cost_json: m.cost_json.clone(),
        reference_steps: m.reference_steps,
    }
}

fn latency_to_pb(l: &Latency) -> pb::LatencyPercentiles {
    pb::LatencyPercentiles {
        p50_us: l.p50_us,
        p99_us: l.p99_us,
        p999_us: l.p999_us,
        max_us: l.max_us,
        count: l.count,
    }
}

pub fn status_to_pb(
    s: &StatusSnapshot,
    token_required: bool,
    max_upload_bytes: usize,
) -> pb::Status {
    let l = &s.loop_status;
    let mode = if l.experiment.running {
        l.experiment.kind.clone()
    } else {
        "idle".to_string()
    };
    pb::Status {
        loop_alive: l.alive,
        mode,
        clock: l.clock.clone(),
        rate_hz: l.rate_hz,
        step: l.step,
        fallbacks: l.fallbacks,
        deadline_misses: l.deadline_misses,
        scheduling: l.scheduling.clone(),
        recorder: l.recorder.clone(),
        recorder_failed: l.recorder_failed(),
        telemetry_drops: l.telemetry_drops,
        board: l.board.clone(),
        experiment: Some(pb::ExperimentStatus {
            kind: l.experiment.kind.clone(),
            running: l.experiment.running,
            cycle: l.experiment.cycle,
            phase: l.experiment.phase.clone(),
        }),
        active_model: s.active_model.as_ref().map(model_to_pb),
        inference_latency: Some(latency_to_pb(&s.server.inference_latency)),
        round_trip_latency: Some(latency_to_pb(&l.round_trip_latency)),
        overruns: l.overruns,
        period_jitter: Some(latency_to_pb(&l.period_jitter)),
        on_time: l.on_time,
        late_one: l.late_one,
        held: l.held,
        fallback: l.fallback,
        corrupt: l.corrupt,
        max_transition_step_n: l.max_transition_step_n,
        saturated: l.saturated,
        board_faults: l.board_faults,
        board_fault: l.board_fault.clone(),
        board_fifo_overflows: l.board_fifo_overflows,
        board_quadrature_errors: l.board_quadrature_errors,
        passivity: Some(pb::PassivityStatus {
            on: l.passivity.on,
            energy_j: l.passivity.energy_j,
            received_j: l.passivity.received_j,
            returned_j: l.passivity.returned_j,
            damping_ns_per_m: l.passivity.damping_ns_per_m,
            active_steps: l.passivity.active_steps,
        }),
        predictions: s.server.predictions,
        uptime_s: s.server.uptime_s,
        server_version: s.server.version.clone(),
        token_required,
        max_upload_bytes: max_upload_bytes as u64,
    }
}
