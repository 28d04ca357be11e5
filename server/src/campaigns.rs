//! Campaigns on the server: a campaign is stored as its `repose_campaign::Campaign` document
//! plus the batches it issued. When one of its batches has been analysed, [`advance`] feeds the
//! runs to the campaign and issues the next batch (or records the end) in one transaction. The
//! same call at start-up resumes campaigns whose batch finished while the server was down.

use repose_api::{BatchState, RunView};
use repose_campaign::{
    Campaign, CampaignRequest, Next, ReportPictures, StageKind, StageResult, StageTemplate, Status,
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

/// Validates the request, plans its first batch and stores both; returns (campaign, batch) ids.
pub async fn create(
    state: &AppState,
    request: CampaignRequest,
    owner: &str,
) -> Result<(Uuid, Uuid), AppError> {
    let name = request.name.clone();
    let (campaign, first) = tokio::task::spawn_blocking(move || {
        let (campaign, first) = Campaign::start(request).map_err(campaign_error)?;
        // With several experiments only the first one's batch is submitted now; the others'
        // screening batches (the same design on their own templates) are checked here too, so
        // an unknown kind or a bad spec is refused before anything runs.
        let r = &campaign.request;
        for key in r.experiment_keys().iter().skip(1) {
            let mut other = first.clone();
            other.experiment = r.template_for(StageTemplate::Screening, key);
            submit::plan_batch(other, 0).map_err(|err| {
                prefix_field(
                    err,
                    &format!("campaign's screening batch of experiment `{key}`"),
                )
            })?;
        }
        let plan = submit::plan_batch(first, Uuid::new_v4().as_u64_pair().0)
            .map_err(|err| prefix_field(err, "campaign's screening batch"))?;
        Ok::<_, AppError>((campaign, plan))
    })
    .await
    .map_err(|err| AppError::Internal(format!("campaign planning task: {err}")))??;
    let id = Uuid::new_v4();
    let batch_id = state
        .db
        .insert_campaign(
            id,
            &name,
            owner,
            CampaignUpdate {
                status: status_label(&campaign.status),
                stage: &stage_label(&campaign),
                state: serde_json::to_string(&campaign)?,
                next: Some(&first),
            },
        )
        .await?;
    crate::orchestrate::jobs_available(state);
    Ok((id, batch_id))
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

/// Moves the campaign that owns `batch_id` on, if that batch is its outstanding one and has
/// finished. Safe to call more than once (the store refuses a second advance of the same step).
pub async fn advance_after_batch(state: &AppState, batch_id: Uuid) -> Result<(), AppError> {
    let Some((campaign_id, index)) = state.db.campaign_of_batch(batch_id).await? else {
        return Ok(());
    };
    advance(state, campaign_id, Some(index)).await
}

/// Advances a running campaign whose outstanding batch is finished (any batch when
/// `only_index` is `None`, as at start-up).
pub async fn advance(
    state: &AppState,
    campaign_id: Uuid,
    only_index: Option<i64>,
) -> Result<(), AppError> {
    let Some(record) = state.db.campaign(campaign_id).await? else {
        return Ok(());
    };
    let mut campaign = decode(&record)?;
    let Some(outstanding) = campaign.outstanding() else {
        return Ok(());
    };
    if only_index.is_some_and(|i| i != outstanding as i64) {
        return Ok(());
    }
    let Some(&batch_id) = record.batch_ids.get(outstanding) else {
        return Err(AppError::Internal(format!(
            "campaign {campaign_id} has no batch #{outstanding}"
        )));
    };
    let Some(status) = state.db.batch_status(batch_id).await? else {
        return Ok(());
    };
    let runs: Vec<RunView> = match status.summary.state {
        BatchState::Active => return Ok(()),
        BatchState::Cancelled => Vec::new(),
        BatchState::Completed => state
            .db
            .list_runs(batch_id)
            .await?
            .map(|(_, runs)| runs)
            .unwrap_or_default(),
    };
    let analysis = state.db.analysis(batch_id).await?;
    let next = if status.summary.state == BatchState::Cancelled {
        let reason = format!("batch {batch_id} of the campaign was cancelled");
        campaign.status = Status::NeedsAttention {
            reason: reason.clone(),
        };
        Next::NeedsAttention(reason)
    } else {
        let finished = StageResult {
            batch: outstanding,
            runs,
            analysis,
        };
        let (advanced, next) = tokio::task::spawn_blocking(move || {
            let next = campaign.advance(&finished);
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
                Next::NeedsAttention(reason)
            }
        }
    };
    let plan = match &next {
        Next::Submit(request) => {
            let request = request.clone();
            let planned = tokio::task::spawn_blocking(move || {
                submit::plan_batch(request, Uuid::new_v4().as_u64_pair().0)
            })
            .await
            .map_err(|err| AppError::Internal(format!("planning task: {err}")))?;
            match planned {
                Ok(plan) => Some(plan),
                Err(err) => {
                    // The generated batch is invalid (e.g. a range clamped to nothing): stop
                    // and say why rather than loop.
                    campaign.status = Status::NeedsAttention {
                        reason: format!("the next batch is not valid: {err}"),
                    };
                    None
                }
            }
        }
        Next::Finished(_) | Next::NeedsAttention(_) => None,
    };
    let stage = stage_label(&campaign);
    let update = CampaignUpdate {
        status: status_label(&campaign.status),
        stage: &stage,
        state: serde_json::to_string(&campaign)?,
        next: plan.as_ref(),
    };
    match state
        .db
        .advance_campaign(
            campaign_id,
            record.batches_issued,
            record.owner.as_deref(),
            update,
        )
        .await?
    {
        None => tracing::debug!(campaign = %campaign_id, "campaign already advanced"),
        Some(Some(new_batch)) => {
            crate::orchestrate::jobs_available(state);
            tracing::info!(campaign = %campaign_id, batch = %new_batch, stage = %stage,
                "campaign issued its next batch");
        }
        Some(None) => {
            tracing::info!(campaign = %campaign_id, status = status_label(&campaign.status),
                "campaign ended")
        }
    }
    Ok(())
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
