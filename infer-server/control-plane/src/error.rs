//! The errors a `Backend` and the control plane return, and how they map to gRPC codes and HTTP
//! statuses (the same error gives the same answer on both sides).
use axum::http::StatusCode;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ControlError {
    /// The request or the model itself is bad: a corrupt file, wrong input/output shapes, a
    /// warm-up that produced NaN, a malformed name or parameter. gRPC INVALID_ARGUMENT, HTTP 400.
    #[error("{0}")]
    InvalidArgument(String),
    /// The request is well-formed but the system is not in a state to do it: the model needs
    /// features the loop does not provide, the model is not loaded, the active model cannot be
    /// unloaded, no loop is attached. gRPC FAILED_PRECONDITION, HTTP 412.
    #[error("{0}")]
    FailedPrecondition(String),
    /// No model by that name. gRPC NOT_FOUND, HTTP 404.
    #[error("{0}")]
    NotFound(String),
    /// The bearer token is missing or wrong. gRPC UNAUTHENTICATED, HTTP 401.
    #[error("{0}")]
    Unauthenticated(String),
    /// A browser request from another site. gRPC PERMISSION_DENIED, HTTP 403.
    #[error("{0}")]
    Forbidden(String),
    /// An uploaded model is over the configured size limit. gRPC RESOURCE_EXHAUSTED, HTTP 413.
    #[error("{0}")]
    TooLarge(String),
    /// The backend cannot answer now (e.g. the inference thread is gone). gRPC UNAVAILABLE,
    /// HTTP 503.
    #[error("{0}")]
    Unavailable(String),
    /// A bug or an unexpected failure. gRPC INTERNAL, HTTP 500.
    #[error("{0}")]
    Internal(String),
}

impl ControlError {
    pub fn grpc_code(&self) -> tonic::Code {
        match self {
            Self::InvalidArgument(_) => tonic::Code::InvalidArgument,
            Self::FailedPrecondition(_) => tonic::Code::FailedPrecondition,
            Self::NotFound(_) => tonic::Code::NotFound,
            Self::Unauthenticated(_) => tonic::Code::Unauthenticated,
            Self::Forbidden(_) => tonic::Code::PermissionDenied,
            Self::TooLarge(_) => tonic::Code::ResourceExhausted,
            Self::Unavailable(_) => tonic::Code::Unavailable,
            Self::Internal(_) => tonic::Code::Internal,
        }
    }

    pub fn http_status(&self) -> StatusCode {
        match self {
            Self::InvalidArgument(_) => StatusCode::BAD_REQUEST,
            Self::FailedPrecondition(_) => StatusCode::PRECONDITION_FAILED,
            Self::NotFound(_) => StatusCode::NOT_FOUND,
            Self::Unauthenticated(_) => StatusCode::UNAUTHORIZED,
            Self::Forbidden(_) => StatusCode::FORBIDDEN,
            Self::TooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            Self::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
            Self::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    /// A short label for metrics.
    pub fn label(&self) -> &'static str {
        match self {
            Self::InvalidArgument(_) => "invalid_argument",
            Self::FailedPrecondition(_) => "failed_precondition",
            Self::NotFound(_) => "not_found",
            Self::Unauthenticated(_) => "unauthenticated",
            Self::Forbidden(_) => "forbidden",
            Self::TooLarge(_) => "too_large",
            Self::Unavailable(_) => "unavailable",
            Self::Internal(_) => "internal",
        }
    }
}

impl From<ControlError> for tonic::Status {
    fn from(e: ControlError) -> Self {
        tonic::Status::new(e.grpc_code(), e.to_string())
    }
}
