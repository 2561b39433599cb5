//! The OpenAPI 3.1 document of the service, made from the one table of routes
//! (`http::routes`), so that it cannot disagree with what the router serves.

use super::auth::Role;
use serde_json::{json, Map, Value};

/// What the document says of a route.
pub struct Described<'a> {
    pub method: &'a str,
    pub path: &'a str,
    pub role: Option<Role>,
    pub summary: &'a str,
}

pub fn document<'a>(routes: impl Iterator<Item = Described<'a>>) -> Value {
    let mut paths = Map::new();
    for r in routes {
        let entry = paths.entry(r.path.to_string()).or_insert_with(|| json!({}));
        let mut op = json!({
            "summary": r.summary,
            "responses": {
                "200": {"description": "done; the body is JSON (the page and live.png excepted)"},
                "4XX": {"description": "refused: {error, message}"},
            },
        });
        if r.path.contains("{id}") {
            op["parameters"] = json!([{"name": "id", "in": "path", "required": true, "schema": {"type": "integer", "minimum": 0}}]);
        }
        match r.role {
            Some(role) => {
                op["security"] = json!([{"bearer": []}]);
                op["x-role"] = json!(role.name());
            }
            None => op["security"] = json!([]),
        }
        entry[r.method.to_ascii_lowercase()] = op;
    }
    json!({
        "openapi": "3.1.0",
        "info": {
            "title": "rig serve",
            "version": env!("CARGO_PKG_VERSION"),
            "description": "The rig as a lab service: a queue of scans and stage moves, run control, live events and a live view. Roles: observer < operator < admin (x-role on each operation). docs/service.md is the guide.",
        },
        "components": {"securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}}},
        "paths": paths,
    })
}
