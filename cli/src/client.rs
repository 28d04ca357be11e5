//! `repose submit`, `repose status`, `repose watch`: a person's side of the job server, over
//! HTTP with the API token from `REPOSE_TOKEN`.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use repose_api::{
    ApiError, BatchCreated, BatchState, BatchStatus, BatchSummary, CampaignCreated, CampaignView,
    RunState, RunView,
};
use reqwest::StatusCode;
use serde::de::DeserializeOwned;
use uuid::Uuid;

/// Where the server is and who is asking.
#[derive(Debug, Clone, Args)]
pub struct ServerArgs {
    /// Job server URL.
    #[arg(long, env = "REPOSE_SERVER", default_value = "http://127.0.0.1:8080")]
    pub server: String,
    /// API token (`repose token create NAME`, or printed by `repose up`).
    #[arg(long, env = "REPOSE_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
}

#[derive(Debug, Args)]
pub struct SubmitArgs {
    /// Batch file (JSON, a `BatchRequest`; see examples/batches/).
    pub file: PathBuf,
    #[command(flatten)]
    pub server: ServerArgs,
    /// Follow the batch with a progress bar and print its analysis when it finishes.
    #[arg(long)]
    pub watch: bool,
}

#[derive(Debug, Args)]
pub struct StatusArgs {
    /// One batch (default: list all).
    pub batch: Option<Uuid>,
    #[command(flatten)]
    pub server: ServerArgs,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct CampaignArgs {
    /// Campaign file (JSON, a `CampaignRequest`; see examples/campaigns/).
    pub file: PathBuf,
    #[command(flatten)]
    pub server: ServerArgs,
    /// Follow the campaign, printing its decisions as they are taken, until it ends.
    #[arg(long)]
    pub watch: bool,
}

#[derive(Debug, Args)]
pub struct WatchArgs {
    /// Batch to follow.
    pub batch: Uuid,
    #[command(flatten)]
    pub server: ServerArgs,
    /// Poll interval, seconds.
    #[arg(long, default_value_t = 1.0)]
    pub interval_s: f64,
}

/// Typed calls a person makes.
#[derive(Debug, Clone)]
pub struct UserClient {
    http: reqwest::Client,
    base: String,
    token: Option<String>,
}

impl UserClient {
    pub fn new(server: &str, token: Option<String>) -> Result<UserClient> {
        let http = reqwest::Client::builder()
            .connect_timeout(Duration::from_secs(5))
            // The server closes connections idle for its header-read timeout (30 s); dropping
            // ours sooner avoids sending a request on a connection it is closing.
            .pool_idle_timeout(Duration::from_secs(20))
            .timeout(Duration::from_secs(60))
            .build()
            .context("cannot build the HTTP client")?;
        Ok(UserClient {
            http,
            base: server.trim_end_matches('/').to_owned(),
            token,
        })
    }

    /// The server's base URL.
    pub fn base(&self) -> &str {
        &self.base
    }

    fn request(&self, method: reqwest::Method, path: &str) -> reqwest::RequestBuilder {
        let builder = self.http.request(method, format!("{}{path}", self.base));
        match &self.token {
            Some(token) => builder.bearer_auth(token),
            None => builder,
        }
    }

    async fn send(&self, builder: reqwest::RequestBuilder) -> Result<(StatusCode, Vec<u8>)> {
        let response = builder
            .send()
            .await
            .with_context(|| format!("cannot reach the server at {}", self.base))?;
        let status = response.status();
        let body = response
            .bytes()
            .await
            .context("reading the reply")?
            .to_vec();
        Ok((status, body))
    }

    async fn expect<T: DeserializeOwned>(&self, builder: reqwest::RequestBuilder) -> Result<T> {
        let (status, body) = self.send(builder).await?;
        if !status.is_success() {
            bail!("{}", describe_error(status, &body));
        }
        serde_json::from_slice(&body).context("unexpected reply from the server")
    }

    /// Submits a batch document as is (the server validates it).
    pub async fn submit(&self, batch: &serde_json::Value) -> Result<BatchCreated> {
        self.expect(
            self.request(reqwest::Method::POST, "/v1/batches")
                .json(batch),
        )
        .await
    }

    /// Starts a campaign (the server validates the document).
    pub async fn start_campaign(&self, campaign: &serde_json::Value) -> Result<CampaignCreated> {
        self.expect(
            self.request(reqwest::Method::POST, "/v1/campaigns")
                .json(campaign),
        )
        .await
    }

    pub async fn campaign(&self, id: Uuid) -> Result<CampaignView> {
        self.expect(self.request(reqwest::Method::GET, &format!("/v1/campaigns/{id}")))
            .await
    }

    /// Follows a campaign to its end, printing each new decision once; returns the final view.
    pub async fn follow_campaign(&self, id: Uuid, interval: Duration) -> Result<CampaignView> {
        let bar = progress_bar(false);
        bar.set_length(100);
        let mut printed = 0;
        loop {
            let view = self.campaign(id).await?;
            for decision in view.decisions.iter().skip(printed) {
                let line = format!("[{}] {}", decision.stage, decision.text);
                // Without a terminal the bar is hidden and would swallow the line.
                if bar.is_hidden() {
                    println!("{line}");
                } else {
                    bar.println(line);
                }
            }
            printed = view.decisions.len();
            bar.set_position(view.stage_percent_done.unwrap_or(0.0).round() as u64);
            let wait = view
                .summary
                .gpu_wait
                .map(|wait| format!(" ({wait})"))
                .unwrap_or_default();
            bar.set_message(format!(
                "campaign {}: stage {}, batch {}{wait}",
                view.summary.status, view.summary.stage, view.summary.batches
            ));
            if view.summary.status != "running" {
                bar.finish_and_clear();
                return Ok(view);
            }
            tokio::time::sleep(interval).await;
        }
    }

    pub async fn campaigns(&self) -> Result<Vec<repose_api::CampaignSummary>> {
        self.expect(self.request(reqwest::Method::GET, "/v1/campaigns"))
            .await
    }

    /// The registered workers (`GET /v1/workers`).
    pub async fn workers(&self) -> Result<Vec<repose_api::WorkerView>> {
        self.expect(self.request(reqwest::Method::GET, "/v1/workers"))
            .await
    }

    pub async fn batches(&self) -> Result<Vec<BatchSummary>> {
        self.expect(self.request(reqwest::Method::GET, "/v1/batches"))
            .await
    }

    pub async fn batch(&self, id: Uuid) -> Result<BatchStatus> {
        self.expect(self.request(reqwest::Method::GET, &format!("/v1/batches/{id}")))
            .await
    }

    /// Every run of a batch, in run order.
    pub async fn runs(&self, id: Uuid) -> Result<Vec<RunView>> {
        self.expect(self.request(reqwest::Method::GET, &format!("/v1/batches/{id}/runs")))
            .await
    }

    /// Prints one line per dead run of batch `id` (its factors and why it failed), so a batch
    /// with failed runs says why, not only how many.
    pub async fn print_dead_runs(&self, id: Uuid) -> Result<()> {
        for run in self.runs(id).await? {
            if run.status != RunState::Dead {
                continue;
            }
            let factors: Vec<String> = run
                .factors
                .iter()
                .map(|f| format!("{} {}", f.name, f.natural))
                .collect();
            println!(
                "  dead run {} ({}): {}",
                run.run_index,
                factors.join(", "),
                run.last_error.as_deref().unwrap_or("no message")
            );
        }
        Ok(())
    }

    /// The analysis as text; `None` while it is not ready yet.
    pub async fn analysis_text(&self, id: Uuid) -> Result<Option<String>> {
        let (status, body) = self
            .send(self.request(
                reqwest::Method::GET,
                &format!("/v1/batches/{id}/analysis?format=text"),
            ))
            .await?;
        match status {
            StatusCode::OK => Ok(Some(String::from_utf8_lossy(&body).into_owned())),
            StatusCode::CONFLICT => Ok(None),
            _ => bail!("{}", describe_error(status, &body)),
        }
    }

    /// Follows a batch with a progress bar until it finishes; returns its final status and,
    /// for a completed batch, the analysis text.
    pub async fn watch(
        &self,
        id: Uuid,
        interval: Duration,
        bar: &ProgressBar,
    ) -> Result<(BatchStatus, Option<String>)> {
        let status = loop {
            let status = self.batch(id).await?;
            let counts = status.summary.counts;
            bar.set_length(counts.total().max(1));
            bar.set_position(counts.finished());
            let eta = status
                .eta_s
                .map(|s| format!(", ~{} left", human_duration(s)))
                .unwrap_or_default();
            let wait = status
                .summary
                .gpu_wait
                .map(|wait| format!(" ({wait})"))
                .unwrap_or_default();
            bar.set_message(format!(
                "{}: {} running, {} queued, {} dead{eta}{wait}",
                status.summary.name, counts.running, counts.queued, counts.dead
            ));
            if status.summary.state != BatchState::Active {
                break status;
            }
            tokio::time::sleep(interval).await;
        };
        bar.finish_and_clear();
        if status.summary.state != BatchState::Completed {
            return Ok((status, None));
        }
        // The analysis is computed right after the last run; give it a moment.
        for _ in 0..600 {
            if let Some(text) = self.analysis_text(id).await? {
                return Ok((status, Some(text)));
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        bail!("batch {id} finished but its analysis did not appear within a minute")
    }
}

/// `"400 Bad Request: factors[0].low: must be …"` from an error reply.
pub fn describe_error(status: StatusCode, body: &[u8]) -> String {
    match serde_json::from_slice::<ApiError>(body) {
        Ok(ApiError {
            error,
            field: Some(field),
        }) => format!("server answered {status}: {field}: {error}"),
        Ok(ApiError { error, field: None }) => format!("server answered {status}: {error}"),
        Err(_) => format!(
            "server answered {status}: {}",
            String::from_utf8_lossy(body)
                .chars()
                .take(300)
                .collect::<String>()
        ),
    }
}

pub fn human_duration(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    match s {
        0..=119 => format!("{s} s"),
        120..=7199 => format!("{} min", (s + 30) / 60),
        _ => format!("{:.1} h", s as f64 / 3600.0),
    }
}

pub fn progress_bar(hidden: bool) -> ProgressBar {
    let bar = if hidden {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(1)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} runs {msg}",
        )
        .expect("valid template"),
    );
    bar.enable_steady_tick(Duration::from_millis(200));
    bar
}

/// Reads a batch file as JSON (the server checks the contents).
pub fn read_batch_file(path: &PathBuf) -> Result<serde_json::Value> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{} is not valid JSON", path.display()))
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}

pub fn submit(args: &SubmitArgs) -> Result<()> {
    let batch = read_batch_file(&args.file)?;
    let client = UserClient::new(&args.server.server, args.server.token.clone())?;
    runtime()?.block_on(async {
        let created = client.submit(&batch).await?;
        println!("{} ({} runs)", created.id, created.run_count);
        if args.watch {
            finish_watch(&client, created.id, Duration::from_secs(1)).await?;
        }
        Ok(())
    })
}

pub fn campaign(args: &CampaignArgs) -> Result<()> {
    let document = read_batch_file(&args.file)?;
    let client = UserClient::new(&args.server.server, args.server.token.clone())?;
    runtime()?.block_on(async {
        let created = client.start_campaign(&document).await?;
        println!("{} (first batch {})", created.id, created.first_batch);
        if args.watch {
            let view = client
                .follow_campaign(created.id, Duration::from_secs(1))
                .await?;
            print_campaign_end(&view, &args.server.server);
        }
        Ok(())
    })
}

/// The end of a campaign in a few lines: status, calibrated values, where the report is.
pub fn print_campaign_end(view: &CampaignView, server: &str) {
    println!(
        "campaign {} {}: {} batches",
        view.summary.id, view.summary.status, view.summary.batches
    );
    if let Some(reason) = &view.reason {
        println!("needs attention: {reason}");
    }
    if let Some(result) = &view.result {
        println!(
            "{}",
            serde_json::to_string_pretty(result).unwrap_or_default()
        );
    }
    println!(
        "report: {}/v1/campaigns/{}/report (HTML; ?format=json)",
        server.trim_end_matches('/'),
        view.summary.id
    );
}

pub fn status(args: &StatusArgs) -> Result<()> {
    let client = UserClient::new(&args.server.server, args.server.token.clone())?;
    runtime()?.block_on(async {
        match args.batch {
            Some(id) => {
                let status = client.batch(id).await?;
                if args.json {
                    println!("{}", serde_json::to_string_pretty(&status)?);
                } else {
                    println!("{}", batch_header());
                    println!("{}", batch_line(&status.summary));
                    if let Some(wait) = status.summary.gpu_wait {
                        println!("{wait}");
                    }
                    if let Some(eta) = status.eta_s {
                        println!("estimated time left: {}", human_duration(eta));
                    }
                    if status.analysis_ready {
                        println!("analysis ready: repose watch {id} prints it");
                    }
                }
            }
            None => {
                let batches = client.batches().await?;
                if args.json {
                    println!("{}", serde_json::to_string_pretty(&batches)?);
                } else {
                    println!("{}", batch_header());
                    for batch in &batches {
                        println!("{}", batch_line(batch));
                        if let Some(wait) = batch.gpu_wait {
                            println!("{:<36}  {wait}", "");
                        }
                    }
                }
            }
        }
        Ok(())
    })
}

pub fn watch(args: &WatchArgs) -> Result<()> {
    if !(args.interval_s.is_finite() && (0.05..=86_400.0).contains(&args.interval_s)) {
        bail!("--interval-s must be between 0.05 and 86400");
    }
    let client = UserClient::new(&args.server.server, args.server.token.clone())?;
    runtime()?.block_on(finish_watch(
        &client,
        args.batch,
        Duration::from_secs_f64(args.interval_s),
    ))
}

/// Watches a batch to its end and prints the outcome (the analysis table when completed).
pub async fn finish_watch(client: &UserClient, id: Uuid, interval: Duration) -> Result<()> {
    let bar = progress_bar(false);
    let (status, analysis) = client.watch(id, interval, &bar).await?;
    let counts = status.summary.counts;
    println!(
        "batch {id} {:?}: {} completed, {} dead, {} cancelled",
        status.summary.state, counts.completed, counts.dead, counts.cancelled
    );
    if counts.dead > 0 {
        client.print_dead_runs(id).await?;
    }
    if let Some(text) = analysis {
        println!("{text}");
    }
    Ok(())
}

fn batch_header() -> String {
    format!(
        "{:<36}  {:<24}  {:<6}  {:<9}  {:>6}  {:>5}  {:>5}  {:>5}",
        "batch", "name", "kind", "state", "done%", "queue", "run", "dead"
    )
}

fn batch_line(b: &BatchSummary) -> String {
    let state = match b.state {
        BatchState::Active => "active",
        BatchState::Completed => "completed",
        BatchState::Cancelled => "cancelled",
    };
    let name: String = b.name.chars().take(24).collect();
    format!(
        "{:<36}  {:<24}  {:<6}  {:<9}  {:>6.1}  {:>5}  {:>5}  {:>5}",
        b.id, name, b.kind, state, b.percent_done, b.counts.queued, b.counts.running, b.counts.dead
    )
}
