//! A `rig serve` process for end-to-end tests, and a small HTTP client of it.

use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::Duration;

pub struct Server {
    pub child: Child,
    pub url: String,
}

impl Server {
    /// Starts `rig serve --bind 127.0.0.1:0 --data DATA --json ARGS…` and waits until it listens.
    pub fn start(data: &Path, args: &[&str]) -> Server {
        let mut child = super::rig()
            .arg("serve")
            .args(["--bind", "127.0.0.1:0", "--json", "--data"])
            .arg(data)
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start rig serve");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let v: Value =
            serde_json::from_str(&line).unwrap_or_else(|e| panic!("rig serve said {line:?}: {e}"));
        Server {
            child,
            url: v["listening"].as_str().unwrap().to_string(),
        }
    }

    /// SIGKILL, no goodbye.
    pub fn kill(mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }

    pub fn call(
        &self,
        method: &str,
        path: &str,
        token: Option<&str>,
        body: Option<&str>,
    ) -> (u16, Value) {
        call(&self.url, method, path, token, body)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(60)))
        .build()
        .into()
}

/// One request; the status and the JSON body (Null if none or not JSON).
pub fn call(
    url: &str,
    method: &str,
    path: &str,
    token: Option<&str>,
    body: Option<&str>,
) -> (u16, Value) {
    let a = agent();
    let u = format!("{url}{path}");
    let auth = token.map(|t| format!("Bearer {t}"));
    macro_rules! with_auth {
        ($q:expr) => {{
            let mut q = $q;
            if let Some(a) = &auth {
                q = q.header("Authorization", a);
            }
            q
        }};
    }
    let r = match method {
        "GET" => with_auth!(a.get(&u)).call(),
        "DELETE" => with_auth!(a.delete(&u)).call(),
        m => {
            let q = match m {
                "POST" => with_auth!(a.post(&u)),
                "PATCH" => with_auth!(a.patch(&u)),
                "PUT" => with_auth!(a.put(&u)),
                _ => panic!("{m}"),
            };
            match body {
                Some(b) => q.header("Content-Type", "application/json").send(b),
                None => q.send_empty(),
            }
        }
    };
    let mut r = r.unwrap_or_else(|e| panic!("{method} {u}: {e}"));
    let status = r.status().as_u16();
    let v = if path.ends_with(".png") || path == "/" || path.ends_with("/events") {
        Value::Null
    } else {
        r.body_mut().read_json().unwrap_or(Value::Null)
    };
    (status, v)
}

/// Polls `GET path` until `ok` holds of its body, at most `secs` seconds.
pub fn wait_for(s: &Server, path: &str, secs: u64, ok: impl Fn(&Value) -> bool) -> Value {
    let t0 = std::time::Instant::now();
    loop {
        let (_, v) = s.call("GET", path, None, None);
        if ok(&v) {
            return v;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(secs),
            "waited {secs} s for {path}: {v}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}
