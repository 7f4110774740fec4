//! The connection to infer-server's control plane, with the token on every call, and errors
//! turned into sentences a user can act on.
use std::time::Duration;

use haptics_proto::grpc::loop_service_client::LoopServiceClient;
use haptics_proto::grpc::model_service_client::ModelServiceClient;
use tonic::metadata::MetadataValue;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, Endpoint};
use tonic::{Code, Request, Status};

#[derive(Clone)]
pub struct AddToken(Option<MetadataValue<tonic::metadata::Ascii>>);

impl tonic::service::Interceptor for AddToken {
    fn call(&mut self, mut request: Request<()>) -> Result<Request<()>, Status> {
        if let Some(token) = &self.0 {
            request
                .metadata_mut()
                .insert("authorization", token.clone());
        }
        Ok(request)
    }
}

pub type Models = ModelServiceClient<InterceptedService<Channel, AddToken>>;
pub type Loop = LoopServiceClient<InterceptedService<Channel, AddToken>>;

pub struct Client {
    pub models: Models,
    pub looper: Loop,
    pub addr: String,
}

/// A failure, already worded for the user; `code` is the process exit status.
#[derive(Debug)]
pub struct CliError {
    pub message: String,
    pub code: i32,
}

impl CliError {
    pub fn new(message: impl Into<String>, code: i32) -> Self {
        Self {
            message: message.into(),
            code,
        }
    }
}

pub const EXIT_SERVER: i32 = 1;
pub const EXIT_USAGE: i32 = 2;
pub const EXIT_CONNECT: i32 = 3;

/// "127.0.0.1:50051" and "http://127.0.0.1:50051" both work.
pub fn normalize_addr(addr: &str) -> String {
    if addr.contains("://") {
        addr.to_string()
    } else {
        format!("http://{addr}")
    }
}

/// The address when neither a flag, the environment nor a connection file gives one.
pub const DEFAULT_ADDR: &str = "http://127.0.0.1:50051";

/// The largest message hapticctl decodes: the server's own limit on what it accepts
/// (`haptics_proto::grpc::MAX_MESSAGE_BYTES`), so an answer the server may send is never
/// refused here as "decoded message length too large".
pub const MAX_DECODE_BYTES: usize = haptics_proto::grpc::MAX_MESSAGE_BYTES;

/// The address and token to use (docs/control-plane.md, "The connection file"): address =
/// `--addr` > HAPTICS_ADDR > the connection file's `grpc` > [`DEFAULT_ADDR`]; token = `--token` >
/// HAPTICS_TOKEN > the file's token when the address is the file's > none. Empty values count as
/// unset; no file (no server, or an older one) is no error; an unsafe directory or a broken file
/// is said on stderr and ignored.
pub fn resolve(
    addr: Option<&str>,
    token: Option<&str>,
    instance: &str,
) -> Result<(String, Option<String>), CliError> {
    let addr = addr.map(str::trim).filter(|a| !a.is_empty());
    let token = token.filter(|t| !t.is_empty());
    let file = if addr.is_some() && token.is_some() {
        None
    } else {
        match haptics_proto::connection::read(instance) {
            Ok(f) => f,
            Err(haptics_proto::connection::ConnectionError::BadInstance(i)) => {
                return Err(CliError::new(
                    format!("--instance {i:?}: only letters, digits, '.', '_' and '-'"),
                    EXIT_USAGE,
                ))
            }
            Err(e) => {
                eprintln!("hapticctl: ignoring the connection file: {e}");
                None
            }
        }
    };
    let addr = match (addr, &file) {
        (Some(a), _) => normalize_addr(a),
        (None, Some(f)) => f.grpc.clone(),
        (None, None) => DEFAULT_ADDR.to_string(),
    };
    let token = match (token, &file) {
        (Some(t), _) => Some(t.to_string()),
        (None, Some(f)) if normalize_addr(&f.grpc) == addr => f.token.clone(),
        _ => None,
    };
    Ok((addr, token))
}

pub async fn connect(addr: &str, token: Option<&str>) -> Result<Client, CliError> {
    let addr = normalize_addr(addr);
    let endpoint = Endpoint::from_shared(addr.clone())
        .map_err(|e| CliError::new(format!("bad --addr {addr:?}: {e}"), EXIT_USAGE))?
        .connect_timeout(Duration::from_secs(3));
    let channel = endpoint.connect().await.map_err(|e| {
        let mut cause = String::new();
        let mut source: Option<&dyn std::error::Error> = Some(&e);
        while let Some(s) = source {
            cause = s.to_string();
            source = s.source();
        }
        CliError::new(
            format!(
                "cannot reach infer-server at {addr}: {cause}. Is infer-server running? \
                 (start it, or point --addr / HAPTICS_ADDR at its gRPC address)"
            ),
            EXIT_CONNECT,
        )
    })?;
    let token = match token {
        Some(t) => Some(format!("Bearer {t}").parse().map_err(|_| {
            CliError::new("the token has characters a header cannot carry", EXIT_USAGE)
        })?),
        None => None,
    };
    let add = AddToken(token);
    Ok(Client {
        models: ModelServiceClient::with_interceptor(channel.clone(), add.clone())
            .max_decoding_message_size(MAX_DECODE_BYTES)
            .max_encoding_message_size(usize::MAX),
        looper: LoopServiceClient::with_interceptor(channel, add)
            .max_decoding_message_size(MAX_DECODE_BYTES),
        addr,
    })
}

/// Words a failed call, naming it (`call`: the gRPC method, e.g. `GetStatus`).
pub fn explain(call: &str, status: &Status, addr: &str) -> CliError {
    let e = explain_status(status, addr);
    CliError::new(format!("{call} failed: {}", e.message), e.code)
}

fn explain_status(status: &Status, addr: &str) -> CliError {
    let msg = status.message();
    let message = match status.code() {
        Code::Unauthenticated => format!(
            "{msg}\nThis server requires its token: hapticctl reads it from the connection file \
             of the user who started infer-server; otherwise pass --token TOKEN or set \
             HAPTICS_TOKEN."
        ),
        Code::Unavailable => {
            format!("infer-server at {addr} is unavailable: {msg}. Is infer-server running?")
        }
        Code::OutOfRange | Code::ResourceExhausted => format!("too large: {msg}"),
        Code::NotFound => format!("not found: {msg}"),
        Code::InvalidArgument => format!("refused: {msg}"),
        Code::FailedPrecondition => format!("not possible now: {msg}"),
        code => format!("{code:?}: {msg}"),
    };
    CliError::new(message, EXIT_SERVER)
}
