//! Real `repose server` and `repose worker` processes for the service tests: each on
//! 127.0.0.1 with an ephemeral port and a temp SQLite file; their logs go to files in the temp
//! directory (printed when a test fails).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use super::repose_bin;

/// A child process killed (SIGKILL) when dropped.
#[derive(Debug)]
pub struct Proc {
    pub child: Child,
    pub log: PathBuf,
}

impl Proc {
    /// SIGKILL: no cleanup, no release, like a machine losing power.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// SIGTERM, then wait for the exit (at most `timeout`).
    pub fn terminate(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let _ = Command::new("kill")
            .arg("-TERM")
            .arg(self.child.id().to_string())
            .status();
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        None
    }

    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A running server and what talks to it.
#[derive(Debug)]
pub struct Service {
    pub dir: PathBuf,
    pub db: PathBuf,
    pub url: String,
    pub port: u16,
    pub server: Proc,
    pub user_token: String,
    pub worker_token: String,
    http: reqwest::blocking::Client,
}

fn log_file(dir: &Path, name: &str) -> (PathBuf, std::fs::File) {
    let path = dir.join(format!("{name}.log"));
    let file = std::fs::File::create(&path).expect("creating a log file");
    (path, file)
}

/// Runs `repose token create` and returns the secret (the word starting with `rp_`).
pub fn create_token(db: &Path, name: &str, role: &str) -> String {
    let out = Command::new(repose_bin())
        .args(["token", "create", name, "--role", role, "--db"])
        .arg(db)
        .output()
        .expect("running repose token create");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "token create failed: {text} {}",
        String::from_utf8_lossy(&out.stderr)
    );
    text.split_whitespace()
        .find(|w| w.starts_with("rp_"))
        .unwrap_or_else(|| panic!("no token in {text:?}"))
        .to_owned()
}

/// Starts `repose server` on `port` (0: any) and waits for its "listening on" line.
pub fn start_server(
    dir: &Path,
    db: &Path,
    port: u16,
    lease_s: f64,
    name: &str,
) -> (Proc, String, u16) {
    start_server_at(dir, db, &format!("127.0.0.1:{port}"), lease_s, name)
}

/// Starts `repose server` listening on `listen` (`ADDRESS:PORT`, port 0: any) and waits for its
/// "listening on" line.
pub fn start_server_at(
    dir: &Path,
    db: &Path,
    listen: &str,
    lease_s: f64,
    name: &str,
) -> (Proc, String, u16) {
    let (log, file) = log_file(dir, name);
    let mut child = Command::new(repose_bin())
        .args(["server", "--listen", listen, "--db"])
        .arg(db)
        .args(["--lease-s", &lease_s.to_string()])
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::from(file))
        .spawn()
        .expect("spawning repose server");
    let stdout = child.stdout.take().expect("piped stdout");
    let mut line = String::new();
    BufReader::new(stdout)
        .read_line(&mut line)
        .expect("reading the server's first line");
    let url = line
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_owned();
    let port = url.rsplit(':').next().unwrap().parse().unwrap();
    (Proc { child, log }, url, port)
}

impl Service {
    /// A server on a fresh database with one user and one worker token.
    pub fn start(dir: &Path, lease_s: f64) -> Service {
        Service::start_at(dir, lease_s, "127.0.0.1")
    }

    /// [`Service::start`] with the server listening on `address` (any port).
    pub fn start_at(dir: &Path, lease_s: f64, address: &str) -> Service {
        let db = dir.join("repose.db");
        let user_token = create_token(&db, "tester", "user");
        let worker_token = create_token(&db, "workers", "worker");
        let (server, url, port) =
            start_server_at(dir, &db, &format!("{address}:0"), lease_s, "server");
        Service {
            dir: dir.to_owned(),
            db,
            url,
            port,
            server,
            user_token,
            worker_token,
            http: reqwest::blocking::Client::builder()
                .timeout(Duration::from_secs(30))
                .build()
                .unwrap(),
        }
    }

    /// Kills the server (SIGKILL) and starts it again on the same port and database.
    pub fn kill_and_restart(&mut self, lease_s: f64) {
        self.server.kill();
        let (server, url, _) = start_server(&self.dir, &self.db, self.port, lease_s, "server-2");
        self.server = server;
        assert_eq!(url, self.url);
    }

    /// Kills the server (SIGKILL), keeps it down for `down`, and starts it again on the same
    /// port and database.
    pub fn kill_wait_restart(&mut self, lease_s: f64, down: Duration) {
        self.server.kill();
        std::thread::sleep(down);
        let (server, url, _) = start_server(&self.dir, &self.db, self.port, lease_s, "server-2");
        self.server = server;
        assert_eq!(url, self.url);
    }

    /// Kills the server (SIGKILL) and starts it on another database file (a restored backup)
    /// on the same port; the tokens must be in that file.
    pub fn kill_and_restart_on(&mut self, db: &Path, lease_s: f64) {
        self.server.kill();
        let (server, url, _) = start_server(&self.dir, db, self.port, lease_s, "server-restored");
        self.server = server;
        self.db = db.to_owned();
        assert_eq!(url, self.url);
    }

    /// Starts `repose worker` with the worker token; `name` names its log file.
    pub fn start_worker(&self, name: &str, extra: &[&str]) -> Proc {
        self.start_worker_via(name, &[], extra)
    }

    /// [`Service::start_worker`] through a launcher (e.g. `ip netns exec NS`), which must exec
    /// the worker so that killing the child kills the worker.
    pub fn start_worker_via(&self, name: &str, launcher: &[&str], extra: &[&str]) -> Proc {
        self.start_worker_with(name, launcher, extra, &[])
    }

    /// [`Service::start_worker_via`] with extra environment variables.
    pub fn start_worker_with(
        &self,
        name: &str,
        launcher: &[&str],
        extra: &[&str],
        env: &[(&str, &str)],
    ) -> Proc {
        let (log, file) = log_file(&self.dir, name);
        let mut command = match launcher.split_first() {
            Some((program, args)) => {
                let mut command = Command::new(program);
                command.args(args).arg(repose_bin());
                command
            }
            None => Command::new(repose_bin()),
        };
        let child = command
            .args(["worker", "--server", &self.url, "--threads", "1"])
            .args(extra)
            .env("REPOSE_WORKER_TOKEN", &self.worker_token)
            .env("RUST_LOG", "info")
            .envs(env.iter().copied())
            .stdout(Stdio::null())
            .stderr(Stdio::from(file))
            .spawn()
            .expect("spawning repose worker");
        Proc { child, log }
    }

    pub fn get(&self, path: &str) -> Value {
        serde_json::from_str(&self.get_text(path)).expect("JSON reply")
    }

    pub fn get_text(&self, path: &str) -> String {
        let response = self
            .http
            .get(format!("{}{path}", self.url))
            .bearer_auth(&self.user_token)
            .send()
            .expect("GET");
        assert!(
            response.status().is_success(),
            "GET {path}: {}",
            response.status()
        );
        response.text().expect("text reply")
    }

    /// POST JSON as the user; the reply must be a success.
    pub fn post(&self, path: &str, body: &Value) -> Value {
        let response = self
            .http
            .post(format!("{}{path}", self.url))
            .bearer_auth(&self.user_token)
            .json(body)
            .send()
            .expect("POST");
        let status = response.status();
        let reply: Value = response.json().expect("JSON reply");
        assert!(status.is_success(), "POST {path}: {status} {reply}");
        reply
    }

    pub fn submit(&self, batch: &Value) -> String {
        let response = self
            .http
            .post(format!("{}/v1/batches", self.url))
            .bearer_auth(&self.user_token)
            .json(batch)
            .send()
            .expect("POST /v1/batches");
        let status = response.status();
        let body: Value = response.json().expect("JSON reply");
        assert!(status.is_success(), "submit: {status} {body}");
        body["id"].as_str().unwrap().to_owned()
    }

    /// Polls the batch until `done(status)` or the timeout; returns the last status.
    pub fn wait_for(&self, batch: &str, timeout: Duration, done: impl Fn(&Value) -> bool) -> Value {
        let deadline = Instant::now() + timeout;
        loop {
            let status = self.get(&format!("/v1/batches/{batch}"));
            if done(&status) {
                return status;
            }
            assert!(
                Instant::now() < deadline,
                "timed out; last status {status}\n--- server log ---\n{}",
                self.server.log_text()
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Waits until the batch has left the `active` state.
    pub fn wait_finished(&self, batch: &str, timeout: Duration) -> Value {
        self.wait_for(batch, timeout, |s| s["state"] != "active")
    }
}

/// A replay batch (`table_lookup`, the test aid) whose runs each hold their worker `hold_s`.
pub fn replay_batch(points: usize, hold_s: f64) -> Value {
    let rows: Vec<Value> = (0..points)
        .map(|i| serde_json::json!({"x": i as f64, "y": 10.0 + 2.0 * i as f64}))
        .collect();
    let design: Vec<Value> = (0..points).map(|i| serde_json::json!([i as f64])).collect();
    serde_json::json!({
        "name": "replay",
        "experiment": {"kind": "table_lookup", "spec": {"values": {"x": 0.0}, "rows": rows, "hold_s": hold_s}},
        "factors": [{"name": "x", "path": "values.x", "low": 0.0, "high": (points - 1) as f64}],
        "design": {"type": "explicit", "points": design},
        "response": "y",
        "model": if points >= 3 { "linear" } else { "none" },
        "seed": 9
    })
}
