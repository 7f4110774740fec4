//! The operations both servers share: checks (names, sizes, parameters) then a call into the
//! `Backend` on tokio's blocking pool, so a slow load never stalls a runtime worker.
use std::sync::Arc;

use crate::auth::Auth;
use crate::backend::{
    validate_model_name, Activation, Backend, ExperimentRequest, ModelInfo, ModelSource,
    StatusSnapshot,
};
use crate::config::Config;
use crate::error::ControlError;
use crate::host_policy::HostPolicy;
use crate::shutdown::Shutdown;
use crate::stats::Stats;
use crate::uploads::UploadBudget;

#[derive(Clone)]
pub struct Core {
    pub backend: Arc<dyn Backend>,
    pub auth: Auth,
    pub config: Arc<Config>,
    pub stats: Arc<Stats>,
    pub shutdown: Shutdown,
    /// The names HTTP requests may carry in `Host` (DNS rebinding).
    pub hosts: Arc<HostPolicy>,
    /// Bytes of uploads being received, over both servers.
    pub uploads: UploadBudget,
}

impl Core {
    pub fn new(config: Config, backend: Arc<dyn Backend>, shutdown: Shutdown) -> Self {
        Self {
            auth: Auth::new(config.token.as_deref()),
            hosts: Arc::new(HostPolicy::new(
                &[config.http_addr, config.grpc_addr],
                &config.allowed_hosts,
            )),
            uploads: UploadBudget::new(config.max_uploads_in_flight_bytes),
            backend,
            config: Arc::new(config),
            stats: Arc::new(Stats::default()),
            shutdown,
        }
    }

    async fn call<T: Send + 'static>(
        &self,
        f: impl FnOnce(&dyn Backend) -> Result<T, ControlError> + Send + 'static,
    ) -> Result<T, ControlError> {
        let backend = Arc::clone(&self.backend);
        let result = tokio::task::spawn_blocking(move || f(backend.as_ref()))
            .await
            .unwrap_or_else(|e| Err(ControlError::Internal(format!("backend call failed: {e}"))));
        let counter = if result.is_ok() {
            &self.stats.requests_ok
        } else {
            &self.stats.requests_failed
        };
        Stats::add(counter, 1);
        result
    }

    pub async fn list_models(&self) -> Result<Vec<ModelInfo>, ControlError> {
        self.call(|b| b.list_models()).await
    }

    /// Loads from the model directory (`upload` None) or from uploaded bytes.
    pub async fn load_model(
        &self,
        name: String,
        upload: Option<Vec<u8>>,
    ) -> Result<ModelInfo, ControlError> {
        validate_model_name(&name)?;
        let uploaded = upload.is_some();
        let source = match upload {
            Some(bytes) => {
                self.check_upload_size(bytes.len())?;
                ModelSource::Upload { name, bytes }
            }
            None => ModelSource::Directory { name },
        };
        let loaded = self.call(move |b| b.load_model(source)).await;
        if uploaded && loaded.is_err() {
            Stats::add(&self.stats.uploads_refused_invalid, 1);
        }
        loaded
    }

    pub fn check_upload_size(&self, len: usize) -> Result<(), ControlError> {
        let limit = self.config.max_upload_bytes;
        if len > limit {
            Stats::add(&self.stats.uploads_refused_too_large, 1);
            return Err(ControlError::TooLarge(format!(
                "the uploaded model is {len} bytes, over the server's limit of {limit} bytes \
                 ({} MiB); raise it with infer-server --max-upload-mib, or put the file in the \
                 model directory and load it by name",
                limit >> 20
            )));
        }
        Ok(())
    }

    pub async fn activate_model(
        &self,
        name: String,
        load_if_needed: bool,
    ) -> Result<Activation, ControlError> {
        validate_model_name(&name)?;
        self.call(move |b| b.activate_model(&name, load_if_needed))
            .await
    }

    pub async fn unload_model(&self, name: String) -> Result<(), ControlError> {
        validate_model_name(&name)?;
        self.call(move |b| b.unload_model(&name)).await
    }

    pub async fn active_model(&self) -> Result<Option<ModelInfo>, ControlError> {
        self.call(|b| Ok(b.active_model())).await
    }

    pub async fn status(&self) -> Result<StatusSnapshot, ControlError> {
        self.call(|b| Ok(b.status())).await
    }

    pub async fn start_experiment(&self, request: ExperimentRequest) -> Result<(), ControlError> {
        self.call(move |b| b.start_experiment(&request)).await
    }

    pub async fn stop_experiment(&self) -> Result<(), ControlError> {
        self.call(|b| b.stop_experiment()).await
    }
}
