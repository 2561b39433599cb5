//! The newest calibration sessions in the store, as the live view shows them: the pixel
//! session's figures (scales, shears, RMS, the measuring mark) and each session's residual
//! plots.

use super::error::ApiError;
use super::{ok, Answer, App};
use crate::calibrate::session;
use axum::extract::{Path as UrlPath, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

const KINDS: [&str; 2] = ["pixel", "interior"];

fn newest(store: &Path, kind: &str) -> Result<Option<PathBuf>, String> {
    session::newest(store, kind).map_err(|e| format!("{}: {e}", store.display()))
}

/// The residual plots a session drew (`residuals-*.png`), by name.
fn plots(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok()?.file_name().into_string().ok())
                .filter(|n| n.starts_with("residuals-") && n.ends_with(".png"))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

fn summary(store: &Path) -> Value {
    let mut out = serde_json::Map::new();
    for kind in KINDS {
        let v = match newest(store, kind) {
            Err(e) => json!({"error": e}),
            Ok(None) => Value::Null,
            Ok(Some(dir)) => {
                let name = dir.file_name().map(|n| n.to_string_lossy().to_string());
                let plots: Vec<String> = plots(&dir)
                    .into_iter()
                    .map(|p| {
                        format!(
                            "/api/v1/calibration/{kind}/{}/{p}",
                            name.as_deref().unwrap_or("")
                        )
                    })
                    .collect();
                let figures = match kind {
                    "pixel" => crate::calibrate::history::figures(&dir)
                        .map_or_else(|e| json!({"error": e}), |f| json!(f)),
                    _ => Value::Null,
                };
                json!({"session": name, "dir": dir, "figures": figures, "plots": plots})
            }
        };
        out.insert(kind.to_string(), v);
    }
    Value::Object(out)
}

/// GET /api/v1/calibration
pub(super) async fn calibration(State(app): State<App>) -> Answer {
    let store = app.settings.store.clone();
    let v = tokio::task::spawn_blocking(move || summary(&store))
        .await
        .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "internal", e.to_string()))?;
    ok(json!({"store": app.settings.store, "newest": v}))
}

/// GET /api/v1/calibration/{kind}/{session}/{file}: a plot of a session of the store (only
/// sessions and plots the listings give are served: nothing else of the disk is reachable; the
/// session is named, so a plot never belongs to a newer session than its figures).
pub(super) async fn plot(
    State(app): State<App>,
    UrlPath((kind, name, file)): UrlPath<(String, String, String)>,
) -> Result<Response, ApiError> {
    let not_found = |what: String| ApiError::new(StatusCode::NOT_FOUND, "no_plot", what);
    if !KINDS.contains(&kind.as_str()) {
        return Err(not_found(format!(
            "{kind:?} is not a session kind: pixel or interior"
        )));
    }
    let store = app.settings.store.clone();
    let bytes = tokio::task::spawn_blocking(move || -> Result<Vec<u8>, ApiError> {
        let dir = session::list(&store, &kind)
            .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "store", e.to_string()))?
            .into_iter()
            .find(|d| d.file_name().is_some_and(|n| n == name.as_str()))
            .ok_or_else(|| {
                not_found(format!("no {kind} session {name:?} in {}", store.display()))
            })?;
        if !plots(&dir).contains(&file) {
            return Err(not_found(format!(
                "{file:?} is not a plot of {}: GET /api/v1/calibration lists them",
                dir.display()
            )));
        }
        std::fs::read(dir.join(&file))
            .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "store", e.to_string()))
    })
    .await
    .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "internal", e.to_string()))??;
    Ok(([(header::CONTENT_TYPE, "image/png")], bytes).into_response())
}
