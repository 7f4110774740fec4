//! The model registry: the files of the model directory and the models held in memory.
//!
//! States (as `control_plane::ModelState`): a file of the directory that was never loaded is
//! `Available`; a model that was validated against the segment's schema and warmed up, and is
//! kept as a ready [`StepEngine`], is `Loaded`; the one the inference thread runs is `Active`;
//! a model whose last load failed is `Failed`, with the reason.
//!
//! Uploaded models stay in memory only (their bytes are kept while the model is known, so it
//! can be revalidated when a loop with another schema attaches); nothing is ever written into
//! the model directory. An upload under the name of a directory file with different contents
//! is refused, so a name always means one model.
//!
//! Activation moves the loaded engine to the inference thread through the atomic handoff
//! ([`crate::serving::handoff`], one pointer swap between two steps) and returns once the thread has
//! taken it, with the first step the new model answered. The engine the thread gave back goes
//! back to its model, which is `Loaded` again (no reload). Activations and unloads are
//! serialised by one mutex; a load builds its engine off that mutex, within the load time limit
//! ([`crate::model::engine::load_bounded`]), and takes it only to record the result, so a slow or
//! crafted model holds up no swap, unload or status. Uploaded models kept in memory are capped
//! in total ([`Registry::with_max_uploads_held`]). None of this ever touches the inference
//! thread's path.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use control_plane::{
    backend::validate_model_name, Activation, ControlError, ModelInfo, ModelSource, ModelState,
};

use crate::control::inference_control::InferenceControl;
use crate::model::contract::{gains_mismatch, step_mismatch, FeatureSchema};
use crate::model::engine::{load_bounded, StepEngine};
use crate::model::ModelError;

/// How long `activate` waits for the inference thread to take a new engine. It takes it
/// between two steps, or within 100 ms when the attached loop sends nothing.
const TAKE_TIMEOUT: Duration = Duration::from_secs(1);
/// How long `activate` waits for the first step the new model answers before reporting the
/// next step instead (the loop is attached but not stepping the model right now).
const EFFECTIVE_WAIT: Duration = Duration::from_millis(250);

/// Warm-up steps run on the control thread right before a swap (brings the model's weights
/// into the shared cache; its first step on the inference thread is then not a cold one).
const REWARM_RUNS: usize = 8;

enum Source {
    Directory,
    Upload(Arc<[u8]>),
}

/// A failed upload keeps its name, state and reason for the model list, not its bytes: they
/// would count against the cap on uploads held (`--max-uploads-mib`) and refuse good uploads.
fn release_failed_upload(entry: &mut Entry) {
    if let Source::Upload(_) = entry.source {
        entry.source = Source::Upload(Arc::from(Vec::new()));
    }
}

/// A load's checked inputs, before the engine is built.
struct Prepared {
    name: String,
    source: Source,
    bytes: Arc<[u8]>,
    label: PathBuf,
}

/// Uploaded models held in memory at most, in bytes, by default (256 MiB).
pub const DEFAULT_MAX_UPLOADS_HELD: usize = 256 << 20;

struct Entry {
    source: Source,
    size_bytes: u64,
    state: ModelState,
    /// The warm engine of a `Loaded` model (`None` while it is with the inference thread).
    engine: Option<StepEngine>,
    /// What the last successful validation found.
    info: Option<crate::model::ModelInfo>,
    error: Option<String>,
    /// Generation of this model's latest activation (the `model_id` of its answers); 0: never.
    generation: u64,
    /// First step answered, as far as known (refined from the inference thread's counters).
    since_step: Option<u64>,
    /// The schema the active model was last (re)validated against, even if that failed.
    validated_for: Vec<String>,
}

#[derive(Default)]
struct State {
    entries: BTreeMap<String, Entry>,
    active: Option<String>,
}

pub struct Registry {
    server: Arc<InferenceControl>,
    dir: PathBuf,
    ops: Mutex<()>,
    state: Mutex<State>,
    /// Cap on the bytes of uploaded models kept in memory.
    max_uploads_held: usize,
}

/// Maps a refused model to the control plane's error: the model's own faults are
/// INVALID_ARGUMENT, a mismatch with the loop's features FAILED_PRECONDITION.
pub fn control_error(name: &str, e: &ModelError) -> ControlError {
    let msg = format!("model {name} refused ({}): {e}", e.code());
    match e {
        ModelError::MissingFeature { .. } => ControlError::FailedPrecondition(msg),
        ModelError::Unreadable { .. } => ControlError::FailedPrecondition(msg),
        ModelError::Session { .. } => ControlError::Internal(msg),
        ModelError::Busy { .. } => ControlError::Unavailable(msg),
        _ => ControlError::InvalidArgument(msg),
    }
}

impl Registry {
    /// A registry over `dir` (which need not exist yet: it then lists nothing).
    pub fn new(server: Arc<InferenceControl>, dir: impl Into<PathBuf>) -> Self {
        Self {
            server,
            dir: dir.into(),
            ops: Mutex::new(()),
            state: Mutex::new(State::default()),
            max_uploads_held: DEFAULT_MAX_UPLOADS_HELD,
        }
    }

    /// Sets the cap on the bytes of uploaded models kept in memory.
    pub fn with_max_uploads_held(mut self, bytes: usize) -> Self {
        self.max_uploads_held = bytes;
        self
    }

    pub fn server(&self) -> &Arc<InferenceControl> {
        &self.server
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// `rf_six` names `rf_six.onnx` when only the latter exists (in memory or in the model
    /// directory): people type model names without the extension.
    fn canonical_name(&self, name: &str) -> String {
        if name.ends_with(".onnx") || self.lock().entries.contains_key(name) {
            return name.to_string();
        }
        let with_ext = format!("{name}.onnx");
        let known = self.lock().entries.contains_key(&with_ext);
        if !self.dir.join(name).is_file() && (known || self.dir.join(&with_ext).is_file()) {
            with_ext
        } else {
            name.to_string()
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn lock_ops(&self) -> MutexGuard<'_, ()> {
        self.ops.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// `*.onnx` regular files of the directory (hidden files skipped), with their sizes.
    fn directory_files(&self) -> Result<BTreeMap<String, u64>, ControlError> {
        let mut out = BTreeMap::new();
        let rd = match std::fs::read_dir(&self.dir) {
            Ok(rd) => rd,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(out),
            Err(e) => {
                return Err(ControlError::Unavailable(format!(
                    "cannot list the model directory {}: {e}",
                    self.dir.display()
                )))
            }
        };
        for entry in rd.flatten() {
            let Ok(name) = entry.file_name().into_string() else {
                continue;
            };
            if name.starts_with('.') || !name.ends_with(".onnx") {
                continue;
            }
            // Follows symlinks: a link to a model file is a model file.
            match std::fs::metadata(entry.path()) {
                Ok(m) if m.is_file() => {
                    out.insert(name, m.len());
                }
                _ => {}
            }
        }
        Ok(out)
    }

    fn label(&self, name: &str, source: &Source) -> PathBuf {
        match source {
            Source::Directory => self.dir.join(name),
            Source::Upload(_) => PathBuf::from(format!("{name} (uploaded)")),
        }
    }

    fn read_directory_file(&self, name: &str) -> Result<Vec<u8>, ControlError> {
        let path = self.dir.join(name);
        match std::fs::read(&path) {
            Ok(b) => Ok(b),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                Err(ControlError::NotFound(format!(
                    "no model {name:?} in the model directory {}",
                    self.dir.display()
                )))
            }
            Err(e) => Err(ControlError::FailedPrecondition(format!(
                "cannot read model file {}: {e}",
                path.display()
            ))),
        }
    }

    /// Every model of the directory and every model in memory, sorted by name.
    pub fn list(&self) -> Result<Vec<ModelInfo>, ControlError> {
        let files = self.directory_files()?;
        let st = self.lock();
        let mut out: BTreeMap<String, ModelInfo> = files
            .into_iter()
            .map(|(n, size)| (n.clone(), ModelInfo::available(n, size)))
            .collect();
        for (name, e) in &st.entries {
            out.insert(name.clone(), self.info_of(name, e));
        }
        Ok(out.into_values().collect())
    }

    fn info_of(&self, name: &str, e: &Entry) -> ModelInfo {
        let mut m = ModelInfo::available(name, e.size_bytes);
        m.state = e.state;
        m.error = e.error.clone();
        m.model_id = e.generation as u32;
        if let Some(i) = &e.info {
            m.kind = i.kind.as_str().to_string();
            m.features = i.features.clone();
            m.units = i.units.clone();
            m.provenance_json = i.provenance.to_string();
            m.cost_json = i.cost.to_string();
            m.reference_steps = i.reference_steps.unwrap_or(0) as u32;
        }
        if e.state == ModelState::Active {
            m.active_since_step = self.server.effective_step(e.generation).or(e.since_step);
        }
        m
    }

    /// The model serving the loop (`None`: none, or the active one does not fit the loop's
    /// schema, so the loop renders its fallback).
    pub fn active(&self) -> Option<ModelInfo> {
        let st = self.lock();
        let name = st.active.as_ref()?;
        let e = st.entries.get(name)?;
        (e.state == ModelState::Active).then(|| self.info_of(name, e))
    }

    /// Reads, validates (against the attached segment's schema, the nine standard features
    /// while no loop is attached) and warms a model, and keeps it loaded. The model is built
    /// off the registry's lock and within the load time limit ([`load_bounded`]), so a slow or
    /// crafted model holds up no activation, unload or status meanwhile.
    pub fn load(&self, source: ModelSource) -> Result<ModelInfo, ControlError> {
        let prepared = self.prepare(source)?;
        let schema = self.server.schema();
        let result = self.build(&prepared, &schema);
        let _ops = self.lock_ops();
        self.collect_returned();
        self.store(prepared, &schema, result)
    }

    /// The same under the registry's lock (activation of a model not loaded yet).
    fn load_locked(&self, source: ModelSource) -> Result<ModelInfo, ControlError> {
        let prepared = self.prepare(source)?;
        let schema = self.server.schema();
        let result = self.build(&prepared, &schema);
        self.store(prepared, &schema, result)
    }

    /// Bytes of uploaded models held in memory, leaving out `except`.
    fn uploads_held(&self, except: &str) -> usize {
        let st = self.lock();
        st.entries
            .iter()
            .filter(|(n, _)| n.as_str() != except)
            .map(|(_, e)| match &e.source {
                Source::Upload(b) => b.len(),
                Source::Directory => 0,
            })
            .sum()
    }

    /// Refuses an upload that would take the uploads held in memory over the cap.
    fn check_upload_cap(&self, name: &str, len: usize) -> Result<(), ControlError> {
        let held = self.uploads_held(name);
        if held.saturating_add(len) > self.max_uploads_held {
            return Err(ControlError::TooLarge(format!(
                "uploaded models held in memory would take {} bytes with {name} ({len} bytes), \
                 over the server's cap of {} bytes: unload an uploaded model first, or put the \
                 file in the model directory and load it by name",
                held.saturating_add(len),
                self.max_uploads_held
            )));
        }
        Ok(())
    }

    /// Name, source and bytes of a load, checked (name, not the active model, upload cap).
    fn prepare(&self, source: ModelSource) -> Result<Prepared, ControlError> {
        let name = match &source {
            ModelSource::Directory { name } => self.canonical_name(name),
            ModelSource::Upload { name, .. } => name.clone(),
        };
        validate_model_name(&name)?;
        self.refuse_active(&name)?;
        let (source, bytes): (Source, Arc<[u8]>) = match source {
            ModelSource::Directory { .. } => {
                (Source::Directory, self.read_directory_file(&name)?.into())
            }
            ModelSource::Upload { bytes, .. } => match std::fs::read(self.dir.join(&name)) {
                Ok(existing) if existing != bytes => {
                    return Err(ControlError::FailedPrecondition(format!(
                        "the model directory already has a different file named {name:?}; \
                         upload under another name"
                    )))
                }
                // The same bytes as the directory's file: that file.
                Ok(_) => (Source::Directory, bytes.into()),
                Err(_) => {
                    self.check_upload_cap(&name, bytes.len())?;
                    let b: Arc<[u8]> = bytes.into();
                    (Source::Upload(Arc::clone(&b)), b)
                }
            },
        };
        let label = self.label(&name, &source);
        Ok(Prepared {
            name,
            source,
            bytes,
            label,
        })
    }

    fn refuse_active(&self, name: &str) -> Result<(), ControlError> {
        if self.lock().active.as_deref() == Some(name) {
            return Err(ControlError::FailedPrecondition(format!(
                "{name} is the active model: activate another model before reloading it"
            )));
        }
        Ok(())
    }

    /// Builds the engine within the load time limit.
    fn build(&self, p: &Prepared, schema: &FeatureSchema) -> Result<StepEngine, ModelError> {
        let engine = load_bounded(
            self.server.runtime(),
            Arc::clone(&p.bytes),
            &p.label,
            schema,
            self.server.session_config(),
        )?;
        if let Some(why) = engine.cost_warning() {
            eprintln!("infer-server: warning: model {}: {why}", p.name);
        }
        Ok(engine)
    }

    /// Records the outcome of a load (under the registry's lock): the engine kept, or the
    /// model marked `Failed` with why.
    fn store(
        &self,
        p: Prepared,
        schema: &FeatureSchema,
        result: Result<StepEngine, ModelError>,
    ) -> Result<ModelInfo, ControlError> {
        let Prepared {
            name,
            source,
            bytes,
            ..
        } = p;
        // Checked again: another call may have activated it, or uploaded others, meanwhile.
        self.refuse_active(&name)?;
        if let Source::Upload(b) = &source {
            self.check_upload_cap(&name, b.len())?;
        }
        let mut entry = Entry {
            source,
            size_bytes: bytes.len() as u64,
            state: ModelState::Loaded,
            engine: None,
            info: None,
            error: None,
            generation: 0,
            since_step: None,
            validated_for: schema.names().to_vec(),
        };
        let outcome = match result {
            Ok(engine) => {
                entry.info = Some(engine.info().clone());
                entry.engine = Some(engine);
                Ok(())
            }
            Err(e) => {
                let err = control_error(&name, &e);
                entry.state = ModelState::Failed;
                entry.error = Some(err.to_string());
                release_failed_upload(&mut entry);
                Err(err)
            }
        };
        let mut st = self.lock();
        if let Some(old) = st.entries.get(&name) {
            entry.generation = old.generation;
        }
        let info = self.info_of(&name, &entry);
        let replaced = st.entries.insert(name, entry);
        drop(st);
        drop(replaced); // an old engine is freed outside the lock
        outcome.map(|()| info)
    }

    /// Makes `name` the active model (loading it first if it is not loaded and
    /// `load_if_needed`), and returns once the inference thread runs it, with the first step it
    /// answered. When the attached loop sends no steps right now, the step reported is the next
    /// one. FAILED_PRECONDITION when no loop is attached: nothing changes then.
    pub fn activate(&self, name: &str, load_if_needed: bool) -> Result<Activation, ControlError> {
        validate_model_name(name)?;
        let name = self.canonical_name(name);
        let name = name.as_str();
        // A directory model not in memory yet is loaded first, like `load`: off the lock and
        // within the time limit, so a slow model does not hold up other swaps meanwhile.
        if load_if_needed && self.server.attached() {
            let in_memory = self.lock().entries.get(name).is_some_and(|e| {
                matches!(e.state, ModelState::Loaded | ModelState::Active)
                    || matches!(e.source, Source::Upload(_))
            });
            if !in_memory && self.dir.join(name).is_file() {
                self.load(ModelSource::Directory {
                    name: name.to_string(),
                })?;
            }
        }
        let _ops = self.lock_ops();
        self.collect_returned();
        if !self.server.attached() {
            return Err(ControlError::FailedPrecondition(format!(
                "no loop is attached to take {name} (is rt-loop running?); nothing changed"
            )));
        }
        let schema = self.server.schema();
        // An engine validated for this schema, or a fresh one.
        let ready = {
            let mut st = self.lock();
            match st.entries.get_mut(name) {
                Some(e) if e.state == ModelState::Loaded => {
                    e.engine.take_if(|en| en.info().schema == schema.names())
                }
                _ => None,
            }
        };
        let engine = match ready {
            Some(engine) => engine,
            None => self.fresh_engine(name, load_if_needed)?,
        };
        // A state stepped at another period than the loop's would relax at the wrong speed:
        // refused, and kept loaded (the loop's rate is its status block's nominal one; before
        // the loop first publishes it, nothing is known and nothing is refused).
        if let Some(why) = step_mismatch(engine.info().step_s, self.loop_rate_hz()) {
            let mut st = self.lock();
            if let Some(e) = st.entries.get_mut(name) {
                if e.state != ModelState::Active {
                    e.state = ModelState::Loaded;
                    e.info = Some(engine.info().clone());
                    e.engine = Some(engine);
                }
            }
            return Err(ControlError::FailedPrecondition(format!(
                "{name} cannot be served by this loop: {why}; nothing changed"
            )));
        }
        // Features of other filters than the loop's: said (on stderr, where up.sh shows it,
        // and in the swap's answer), not refused: nothing else can serve the model, and at a
        // testing machine's slow rates the two filters agree.
        let loop_gains = self.server.loop_status().map_or((0.0, 0.0), |s| {
            (s.velocity_gain_rad_s, s.acceleration_gain_rad_s)
        });
        let info = engine.info();
        let warnings: Vec<String> = gains_mismatch(info.feature_gains, &info.features, loop_gains)
            .into_iter()
            .collect();
        for why in &warnings {
            eprintln!("infer-server: warning: model {name}: {why}");
        }
        let mut engine = engine;
        engine.rewarm(REWARM_RUNS);
        let label = engine.info().path.clone();
        let info = engine.info().clone();
        let previous = self.server.active();
        let generation = self.server.activate_engine(engine, &label).generation;
        if !self.server.wait_active(generation, TAKE_TIMEOUT) {
            if let Some(offered) = self.server.withdraw(generation, previous) {
                let mut st = self.lock();
                if let Some(e) = st.entries.get_mut(name) {
                    if e.state != ModelState::Active {
                        e.state = ModelState::Loaded;
                        e.error = None;
                        e.info = Some(info);
                        e.engine = Some(offered.engine);
                    }
                }
                return Err(ControlError::FailedPrecondition(format!(
                    "no loop is attached to take {name} (is rt-loop running?); it stays loaded: \
                     activate it again once the loop runs"
                )));
            }
        }
        self.collect_returned();
        let effective_step = self
            .server
            .wait_effective(generation, EFFECTIVE_WAIT)
            .unwrap_or_else(|| {
                let c = self.server.counters();
                let answered = c.answered.load(std::sync::atomic::Ordering::Relaxed);
                let last = c.last_seq.load(std::sync::atomic::Ordering::Relaxed);
                if answered == 0 {
                    0
                } else {
                    last + 1
                }
            });
        let mut st = self.lock();
        if let Some(prev) = st.active.take() {
            if prev != name {
                if let Some(e) = st.entries.get_mut(&prev) {
                    // Its engine comes back from the thread (collect_returned); if it did not
                    // fit the current loop, the next activation reloads it and says so.
                    e.state = ModelState::Loaded;
                    e.error = None;
                    e.since_step = None;
                }
            }
        }
        let e = st
            .entries
            .get_mut(name)
            .expect("fresh_engine or the loaded entry put it there");
        e.state = ModelState::Active;
        e.error = None;
        e.engine = None;
        e.info = Some(info);
        e.generation = generation;
        e.since_step = Some(effective_step);
        e.validated_for = schema.names().to_vec();
        st.active = Some(name.to_string());
        let model = self.info_of(name, st.entries.get(name).expect("just set"));
        Ok(Activation {
            model: ModelInfo {
                active_since_step: Some(effective_step),
                ..model
            },
            effective_step,
            warnings,
        })
    }

    /// The attached loop's nominal rate from its status block, Hz; 0 when no loop has
    /// published one.
    pub fn loop_rate_hz(&self) -> f64 {
        self.server.loop_status().map_or(0.0, |s| s.rate_hz)
    }

    /// A new engine for `name`: reloaded from its source when it is in memory (a loaded engine
    /// validated for another schema, or the active model activated again: it starts afresh),
    /// else loaded from the directory if `load_if_needed`.
    fn fresh_engine(&self, name: &str, load_if_needed: bool) -> Result<StepEngine, ControlError> {
        let known = {
            let st = self.lock();
            st.entries.get(name).map(|e| {
                let bytes = match &e.source {
                    Source::Upload(b) => Some(Arc::clone(b)),
                    Source::Directory => None,
                };
                (e.state, bytes)
            })
        };
        if matches!(&known, Some((ModelState::Failed, Some(b))) if b.is_empty()) {
            return Err(ControlError::FailedPrecondition(format!(
                "{name} is an upload that failed to load; its bytes were not kept: upload it again"
            )));
        }
        let in_memory = matches!(known, Some((ModelState::Loaded | ModelState::Active, _)));
        if !in_memory && !load_if_needed {
            if known.is_none() && !self.dir.join(name).is_file() {
                return Err(ControlError::NotFound(format!(
                    "no model {name:?} in the model directory {} or in memory",
                    self.dir.display()
                )));
            }
            return Err(ControlError::FailedPrecondition(format!(
                "{name} is not loaded: load it first (or activate with load_if_needed)"
            )));
        }
        let is_active = known
            .as_ref()
            .is_some_and(|(s, _)| *s == ModelState::Active);
        let source = match known {
            Some((_, Some(bytes))) => ModelSource::Upload {
                name: name.to_string(),
                bytes: bytes.to_vec(),
            },
            _ => ModelSource::Directory {
                name: name.to_string(),
            },
        };
        if is_active {
            // Not through load_locked (it refuses the active model): a second engine, built
            // beside the running one.
            let (src, bytes) = match source {
                ModelSource::Upload { bytes, .. } => {
                    let b: Arc<[u8]> = bytes.into();
                    (Source::Upload(Arc::clone(&b)), b)
                }
                ModelSource::Directory { .. } => {
                    (Source::Directory, self.read_directory_file(name)?.into())
                }
            };
            return load_bounded(
                self.server.runtime(),
                bytes,
                &self.label(name, &src),
                &self.server.schema(),
                self.server.session_config(),
            )
            .map_err(|e| control_error(name, &e));
        }
        self.load_locked(source)?;
        let mut st = self.lock();
        Ok(st
            .entries
            .get_mut(name)
            .and_then(|e| e.engine.take())
            .expect("a successful load keeps its engine"))
    }

    /// Drops a loaded (or failed) model from memory. An uploaded model is forgotten.
    pub fn unload(&self, name: &str) -> Result<(), ControlError> {
        let _ops = self.lock_ops();
        self.collect_returned();
        let name = self.canonical_name(name);
        let name = name.as_str();
        let mut st = self.lock();
        if st.active.as_deref() == Some(name) {
            return Err(ControlError::FailedPrecondition(format!(
                "{name} is the active model: activate another one first"
            )));
        }
        let removed = st.entries.remove(name);
        drop(st);
        match removed {
            Some(_) => Ok(()), // the engine is freed here, outside the lock
            None => Err(ControlError::NotFound(format!(
                "no model {name:?} is loaded"
            ))),
        }
    }

    /// Puts engines the inference thread gave back into their models (by generation); an
    /// engine no model claims (replaced by a reload) is dropped.
    fn collect_returned(&self) {
        while let Some(offered) = self.server.collect_retired() {
            let mut st = self.lock();
            let slot = st.entries.values_mut().find(|e| {
                e.generation == offered.generation
                    && e.state == ModelState::Loaded
                    && e.engine.is_none()
            });
            match slot {
                Some(e) => e.engine = Some(offered.engine),
                None => {
                    drop(st);
                    drop(offered);
                }
            }
        }
    }

    /// Housekeeping, every few tens of milliseconds (skipped while an operation runs):
    /// collects returned engines and revalidates the active model when a loop with another
    /// feature schema attached. Returns a line to log when something happened.
    pub fn maintain(&self) -> Option<String> {
        let _ops = match self.ops.try_lock() {
            Ok(g) => g,
            Err(std::sync::TryLockError::Poisoned(p)) => p.into_inner(),
            Err(std::sync::TryLockError::WouldBlock) => return None,
        };
        self.collect_returned();
        if !self.server.attached() {
            return None;
        }
        let schema = self.server.schema();
        let (name, source) = {
            let st = self.lock();
            let name = st.active.clone()?;
            let e = st.entries.get(&name)?;
            if e.validated_for == schema.names() {
                return None;
            }
            let source = match &e.source {
                Source::Upload(b) => Source::Upload(Arc::clone(b)),
                Source::Directory => Source::Directory,
            };
            (name, source)
        };
        let bytes: Result<Arc<[u8]>, ControlError> = match &source {
            Source::Upload(b) => Ok(Arc::clone(b)),
            Source::Directory => self.read_directory_file(&name).map(Into::into),
        };
        let result = bytes.and_then(|b| {
            load_bounded(
                self.server.runtime(),
                b,
                &self.label(&name, &source),
                &schema,
                self.server.session_config(),
            )
            .map_err(|e| control_error(&name, &e))
        });
        let mut st = self.lock();
        let e = st.entries.get_mut(&name)?;
        e.validated_for = schema.names().to_vec();
        match result {
            Ok(engine) => {
                let label = engine.info().path.clone();
                e.info = Some(engine.info().clone());
                e.state = ModelState::Active;
                e.error = None;
                e.since_step = None;
                e.generation = self.server.activate_engine(engine, &label).generation;
                Some(format!(
                    "a loop with features [{}] attached; {name} revalidated and active again",
                    schema.names().join(", ")
                ))
            }
            Err(err) => {
                // The inference thread answers SCHEMA_MISMATCH (the loop renders its
                // fallback) until a model that fits is activated, or a loop that fits returns.
                e.state = ModelState::Failed;
                e.error = Some(err.to_string());
                Some(format!(
                    "a loop with features [{}] attached; the active model does not fit it, the \
                     loop renders its fallback: {err}",
                    schema.names().join(", ")
                ))
            }
        }
    }
}
