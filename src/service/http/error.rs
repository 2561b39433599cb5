//! The service's errors as clients see them (JSON with a kind to branch on and a message), and
//! the JSON body extractor whose every rejection is one of them.

use crate::service::devices::DeviceError;
use crate::service::ledger::LedgerError;
use crate::service::queue::QueueError;
use crate::service::runner::ControlError;
use crate::service::task::TaskError;
use axum::extract::{FromRequest, Request as HttpRequest};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::json;

/// An error as the client sees it: a status, a kind to branch on, a message to show.
#[derive(Debug)]
pub struct ApiError {
    pub status: StatusCode,
    pub kind: &'static str,
    pub message: String,
}

impl ApiError {
    pub fn new(status: StatusCode, kind: &'static str, message: impl Into<String>) -> Self {
        ApiError {
            status,
            kind,
            message: message.into(),
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (
            self.status,
            Json(json!({"error": self.kind, "message": self.message})),
        )
            .into_response()
    }
}

impl From<QueueError> for ApiError {
    fn from(e: QueueError) -> Self {
        let (s, k) = match e {
            QueueError::NoItem(_) => (StatusCode::NOT_FOUND, "no_item"),
            QueueError::NotQueued { .. } => (StatusCode::CONFLICT, "not_queued"),
            QueueError::Full { .. } => (StatusCode::INSUFFICIENT_STORAGE, "queue_full"),
            QueueError::BadIndex { .. } => (StatusCode::UNPROCESSABLE_ENTITY, "bad_position"),
            _ => (StatusCode::UNPROCESSABLE_ENTITY, "bad_request"),
        };
        ApiError::new(s, k, e.to_string())
    }
}

impl From<LedgerError> for ApiError {
    fn from(e: LedgerError) -> Self {
        match e {
            LedgerError::Queue(q) => q.into(),
            e @ LedgerError::Locked(_) => {
                ApiError::new(StatusCode::LOCKED, "locked", e.to_string())
            }
            e => ApiError::new(StatusCode::SERVICE_UNAVAILABLE, "journal", e.to_string()),
        }
    }
}

impl From<DeviceError> for ApiError {
    fn from(e: DeviceError) -> Self {
        use crate::stage::StageError as S;
        let (s, k) = match &e {
            DeviceError::Busy(_) => (StatusCode::CONFLICT, "busy"),
            DeviceError::NotSimulated => (StatusCode::CONFLICT, "not_simulated"),
            DeviceError::Stage(S::OutOfLimits { .. }) => {
                (StatusCode::UNPROCESSABLE_ENTITY, "out_of_limits")
            }
            DeviceError::Stage(S::NotHomed) => {
                return ApiError::new(
                    StatusCode::CONFLICT,
                    "not_homed",
                    crate::service::devices::NOT_HOMED,
                );
            }
            _ => (StatusCode::BAD_GATEWAY, "device"),
        };
        ApiError::new(s, k, e.to_string())
    }
}

impl From<ControlError> for ApiError {
    fn from(e: ControlError) -> Self {
        match e {
            ControlError::Device(d) => d.into(),
            ControlError::Ledger(l) => l.into(),
            e => ApiError::new(StatusCode::CONFLICT, "state", e.to_string()),
        }
    }
}

impl From<TaskError> for ApiError {
    fn from(e: TaskError) -> Self {
        let k = match &e {
            TaskError::Stage(_) | TaskError::Plan(_) => "out_of_limits",
            _ => "bad_task",
        };
        ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, k, e.to_string())
    }
}

/// A JSON body whose every rejection (syntax, wrong type, no content type, too large) is an
/// [`ApiError`] naming what was wrong.
pub struct Body<T>(pub T);

impl<T: serde::de::DeserializeOwned, S: Send + Sync> FromRequest<S> for Body<T> {
    type Rejection = ApiError;
    async fn from_request(req: HttpRequest, state: &S) -> Result<Self, ApiError> {
        use axum::extract::rejection::JsonRejection as J;
        // A declared length over the limit is refused before a byte of the body is read: a
        // client that sent `Expect: 100-continue` (curl does, above 1 MiB) never uploads it.
        let declared = req
            .headers()
            .get(axum::http::header::CONTENT_LENGTH)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.trim().parse::<u64>().ok());
        if let Some(n) = declared.filter(|&n| n > super::BODY_LIMIT as u64) {
            return Err(ApiError::new(
                StatusCode::PAYLOAD_TOO_LARGE,
                "body",
                format!(
                    "the body is {n} bytes; at most {} are taken",
                    super::BODY_LIMIT
                ),
            ));
        }
        match Json::<T>::from_request(req, state).await {
            Ok(Json(v)) => Ok(Body(v)),
            Err(e) => {
                let kind = match &e {
                    J::JsonDataError(_) => "wrong_type",
                    J::JsonSyntaxError(_) => "malformed_json",
                    J::MissingJsonContentType(_) => "content_type",
                    // Too large (413) or unreadable.
                    _ => "body",
                };
                Err(ApiError::new(e.status(), kind, e.body_text()))
            }
        }
    }
}
