//! Campaigns on the server: a campaign is stored as its `repose_campaign::Campaign` document
//! plus the batches it issued. When one of its batches has been analysed, [`advance`] feeds the
//! runs to the campaign and issues the next batch (or records the end) in one transaction. The
//! same call at start-up resumes campaigns whose batch finished while the server was down.

use repose_api::{BatchState, RunView};
use repose_campaign::{
    Campaign, CampaignRequest, ReportPictures, StageKind, StageResult, StageTemplate, Status, Step,
};
use uuid::Uuid;

use crate::db::{CampaignRecord, CampaignUpdate};
use crate::error::AppError;
use crate::{submit, AppState};

/// The plain-word spelling of a campaign's status, as stored.
pub fn status_label(status: &Status) -> &'static str {
    match status {
        Status::Running => "running",
        Status::Finished => "finished",
        Status::NeedsAttention { .. } => "needs_attention",
    }
}

fn stage_label(campaign: &Campaign) -> String {
    stage_id(campaign.stage)
}

/// A stage's machine-friendly name (`screening`, `steepest`, `response_surface`, …).
pub fn stage_id(stage: repose_campaign::StageKind) -> String {
    match serde_json::to_value(stage) {
        Ok(serde_json::Value::String(id)) => id,
        _ => stage.label().to_owned(),
    }
}

/// Validates the request, plans its first batches (one, or a whole round of the Bayesian
/// strategy) and stores them; returns (campaign, first batch) ids.
pub async fn create(
    state: &AppState,
    request: CampaignRequest,
    owner: &str,
) -> Result<(Uuid, Uuid), AppError> {
    let name = request.name.clone();
    let (campaign, plans) = tokio::task::spawn_blocking(move || {
        let (campaign, first) = Campaign::begin(request).map_err(campaign_error)?;
        let r = &campaign.request;
        if first.len() == 1 {
            // The chain submits only the first experiment's batch now; the others' screening
            // batches (the same design on their own templates) are checked here too, so an
            // unknown kind or a bad spec is refused before anything runs.
            for key in r.experiment_keys().iter().skip(1) {
                let mut other = first[0].clone();
                other.experiment = r.with_backend(r.template_for(StageTemplate::Screening, key));
                submit::plan_batch(other, 0).map_err(|err| {
                    prefix_field(
                        err,
                        &format!("campaign's screening batch of experiment `{key}`"),
                    )
                })?;
            }
        }
        let plans = first
            .into_iter()
            .map(|batch| {
                submit::plan_batch(batch, Uuid::new_v4().as_u64_pair().0)
                    .map_err(|err| prefix_field(err, "campaign's first batch"))
            })
            .collect::<Result<Vec<_>, AppError>>()?;
        Ok::<_, AppError>((campaign, plans))
    })
    .await
    .map_err(|err| AppError::Internal(format!("campaign planning task: {err}")))??;
    let id = Uuid::new_v4();
    let batch_ids = state
        .db
        .insert_campaign(
            id,
            &name,
            owner,
            CampaignUpdate {
                status: status_label(&campaign.status),
                stage: &stage_label(&campaign),
                state: serde_json::to_string(&campaign)?,
                next: &plans,
            },
        )
        .await?;
    crate::orchestrate::jobs_available(state);
    Ok((id, batch_ids[0]))
}

/// The campaign's stored document.
pub fn decode(record: &CampaignRecord) -> Result<Campaign, AppError> {
    serde_json::from_str(&record.state)
        .map_err(|err| AppError::Internal(format!("stored campaign {}: {err}", record.id)))
}

/// The finished batches of a campaign as `StageResult`s, in issue order (for the report).
pub async fn stage_results(
    state: &AppState,
    record: &CampaignRecord,
) -> Result<Vec<StageResult>, AppError> {
    let mut results = Vec::new();
    for (index, batch_id) in record.batch_ids.iter().enumerate() {
        let Some((_, runs)) = state.db.list_runs(*batch_id).await? else {
            continue;
        };
        let analysis = state.db.analysis(*batch_id).await?;
        results.push(StageResult {
            batch: index,
            runs,
            analysis,
        });
    }
    Ok(results)
}

/// The report's pictures: the first stored picture of the last verification batch (a pile)
/// and of the drilling batch (the hole's section), when the workers sent them.
pub async fn report_pictures(
    state: &AppState,
    campaign: &Campaign,
    record: &CampaignRecord,
) -> Result<ReportPictures, AppError> {
    let mut pictures = ReportPictures::default();
    for issued in campaign.batches.iter().rev() {
        let Some(batch_id) = record.batch_ids.get(issued.index) else {
            continue;
        };
        let slot = match issued.stage {
            StageKind::Verification => &mut pictures.verification_pile,
            StageKind::Drilling => &mut pictures.drilled_hole,
            _ => continue,
        };
        if slot.is_some() {
            continue;
        }
        let mut stored = state.db.first_run_pictures(*batch_id).await?;
        *slot = ["pile.svg", "section.svg"]
            .iter()
            .find_map(|name| stored.remove(*name));
    }
    Ok(pictures)
}

/// Moves the campaign that owns `batch_id` on, if that batch is one of its outstanding ones
/// and has finished. Safe to call more than once (the store refuses a second advance of the
/// same step).
pub async fn advance_after_batch(state: &AppState, batch_id: Uuid) -> Result<(), AppError> {
    let Some((campaign_id, index)) = state.db.campaign_of_batch(batch_id).await? else {
        return Ok(());
    };
    advance(state, campaign_id, Some(index)).await
}

/// Concurrent advances of one campaign (two batches of a round finishing together) are
/// serialised by the store; the one that lost re-reads and tries again, at most this often.
const ADVANCE_TRIES: usize = 20;

/// Advances a running campaign with its finished outstanding batch `only_index`, or (when
/// `None`, as at start-up) with every outstanding batch that has finished.
pub async fn advance(
    state: &AppState,
    campaign_id: Uuid,
    only_index: Option<i64>,
) -> Result<(), AppError> {
    let mut tries = 0;
    loop {
        match advance_once(state, campaign_id, only_index).await? {
            Advanced::Nothing => return Ok(()),
            Advanced::Done if only_index.is_some() => return Ok(()),
            // At start-up: feed the next finished batch, if any.
            Advanced::Done => tries = 0,
            Advanced::Raced => {
                tries += 1;
                if tries >= ADVANCE_TRIES {
                    return Err(AppError::Internal(format!(
                        "campaign {campaign_id} kept changing while it was being advanced"
                    )));
                }
                tracing::debug!(campaign = %campaign_id, "campaign advanced meanwhile; again");
            }
        }
    }
}

/// What one attempt of [`advance`] did.
enum Advanced {
    /// No outstanding batch (of the ones asked for) has finished.
    Nothing,
    /// One batch was fed and the step stored.
    Done,
    /// Someone else stored a step since this one read the campaign: nothing written.
    Raced,
}

async fn advance_once(
    state: &AppState,
    campaign_id: Uuid,
    only_index: Option<i64>,
) -> Result<Advanced, AppError> {
    let Some(record) = state.db.campaign(campaign_id).await? else {
        return Ok(Advanced::Nothing);
    };
    let mut campaign = decode(&record)?;
    // The first outstanding batch (of the ones asked for) that has finished.
    let mut found = None;
    for outstanding in campaign.outstanding_batches() {
        if only_index.is_some_and(|i| i != outstanding as i64) {
            continue;
        }
        let Some(&batch_id) = record.batch_ids.get(outstanding) else {
            return Err(AppError::Internal(format!(
                "campaign {campaign_id} has no batch #{outstanding}"
            )));
        };
        let Some(status) = state.db.batch_status(batch_id).await? else {
            continue;
        };
        if status.summary.state != BatchState::Active {
            found = Some((outstanding, batch_id, status.summary.state));
            break;
        }
    }
    let Some((outstanding, batch_id, batch_state)) = found else {
        return Ok(Advanced::Nothing);
    };
    let runs: Vec<RunView> = match batch_state {
        BatchState::Completed => state
            .db
            .list_runs(batch_id)
            .await?
            .map(|(_, runs)| runs)
            .unwrap_or_default(),
        _ => Vec::new(),
    };
    let analysis = state.db.analysis(batch_id).await?;
    let next = if batch_state == BatchState::Cancelled {
        let reason = format!("batch {batch_id} of the campaign was cancelled");
        campaign.status = Status::NeedsAttention {
            reason: reason.clone(),
        };
        Step::NeedsAttention(reason)
    } else {
        let finished = StageResult {
            batch: outstanding,
            runs,
            analysis,
        };
        let (advanced, next) = tokio::task::spawn_blocking(move || {
            let next = campaign.step(&finished);
            (campaign, next)
        })
        .await
        .map_err(|err| AppError::Internal(format!("campaign task: {err}")))?;
        campaign = advanced;
        match next {
            Ok(next) => next,
            Err(err) => {
                let reason = format!("the campaign could not continue: {err}");
                campaign.status = Status::NeedsAttention {
                    reason: reason.clone(),
                };
                Step::NeedsAttention(reason)
            }
        }
    };
    let plans = match &next {
        Step::Submit(requests) => {
            let requests = requests.clone();
            let planned = tokio::task::spawn_blocking(move || {
                requests
                    .into_iter()
                    .map(|request| submit::plan_batch(request, Uuid::new_v4().as_u64_pair().0))
                    .collect::<Result<Vec<_>, AppError>>()
            })
            .await
            .map_err(|err| AppError::Internal(format!("planning task: {err}")))?;
            match planned {
                Ok(plans) => plans,
                Err(err) => {
                    // The generated batch is invalid (e.g. a range clamped to nothing): stop
                    // and say why rather than loop.
                    campaign.status = Status::NeedsAttention {
                        reason: format!("the next batch is not valid: {err}"),
                    };
                    Vec::new()
                }
            }
        }
        Step::Wait | Step::Finished(_) | Step::NeedsAttention(_) => Vec::new(),
    };
    let stage = stage_label(&campaign);
    let update = CampaignUpdate {
        status: status_label(&campaign.status),
        stage: &stage,
        state: serde_json::to_string(&campaign)?,
        next: &plans,
    };
    match state
        .db
        .advance_campaign(
            campaign_id,
            record.batches_issued,
            &record.state,
            record.owner.as_deref(),
            update,
        )
        .await?
    {
        None => return Ok(Advanced::Raced),
        Some(new_batches) if !new_batches.is_empty() => {
            crate::orchestrate::jobs_available(state);
            tracing::info!(campaign = %campaign_id, batches = new_batches.len(), stage = %stage,
                "campaign issued its next batches");
        }
        Some(_) if matches!(campaign.status, Status::Running) => {
            tracing::debug!(campaign = %campaign_id, "campaign waits for the rest of its round")
        }
        Some(_) => {
            tracing::info!(campaign = %campaign_id, status = status_label(&campaign.status),
                "campaign ended")
        }
    }
    Ok(Advanced::Done)
}

/// Resumes every running campaign (called once at start-up).
pub async fn resume_all(state: &AppState) {
    let ids = match state.db.running_campaigns().await {
        Ok(ids) => ids,
        Err(err) => {
            tracing::error!(error = %err, "cannot list running campaigns");
            return;
        }
    };
    for id in ids {
        if let Err(err) = advance(state, id, None).await {
            tracing::error!(campaign = %id, error = %err, "cannot resume campaign");
        }
    }
}

fn campaign_error(err: repose_campaign::CampaignError) -> AppError {
    match err {
        repose_campaign::CampaignError::InvalidRequest { field, reason } => {
            AppError::invalid(field, reason)
        }
        other => AppError::invalid("campaign", other.to_string()),
    }
}

fn prefix_field(err: AppError, what: &str) -> AppError {
    match err {
        AppError::Invalid { field, message } => AppError::Invalid {
            field,
            message: format!("{what}: {message}"),
        },
        other => other,
    }
}
