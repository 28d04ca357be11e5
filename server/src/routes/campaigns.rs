//! `/v1/campaigns`: starting a campaign, listing, progress and the report. The campaign logic
//! itself is [`crate::campaigns`].

use axum::extract::{Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use repose_api::{CampaignBatch, CampaignCreated, CampaignDecision, CampaignSummary, CampaignView};

use super::{check_owner, owner_filter, FormatQuery, PathId, Reader, ValidJson};
use crate::auth::Caller;
use crate::error::AppError;
use crate::{campaigns, AppState};

/// Campaigns listed by `GET /v1/campaigns`.
const CAMPAIGN_LIST_LIMIT: u32 = 200;

pub(super) async fn create_campaign(
    State(state): State<AppState>,
    caller: Caller,
    ValidJson(request): ValidJson<repose_campaign::CampaignRequest>,
) -> Result<(StatusCode, Json<CampaignCreated>), AppError> {
    let (id, first_batch) = campaigns::create(&state, request, &caller.name).await?;
    tracing::info!(campaign = %id, batch = %first_batch, "campaign started");
    Ok((
        StatusCode::CREATED,
        Json(CampaignCreated { id, first_batch }),
    ))
}

pub(super) async fn list_campaigns(
    State(state): State<AppState>,
    reader: Reader,
) -> Result<impl IntoResponse, AppError> {
    let owner = owner_filter(&state, &reader);
    let records = state.db.list_campaigns(CAMPAIGN_LIST_LIMIT, owner).await?;
    Ok(Json(
        records
            .iter()
            .map(campaign_summary)
            .collect::<Vec<CampaignSummary>>(),
    ))
}

fn campaign_summary(record: &crate::db::CampaignRecord) -> CampaignSummary {
    CampaignSummary {
        id: record.id,
        name: record.name.clone(),
        status: record.status.clone(),
        stage: record.stage.clone(),
        batches: u64::try_from(record.batches_issued).unwrap_or(0),
        created_at_ms: record.created_at_ms,
        updated_at_ms: record.updated_at_ms,
        gpu_wait: record.gpu_wait,
    }
}

pub(super) async fn campaign_status(
    State(state): State<AppState>,
    reader: Reader,
    PathId(id): PathId,
) -> Result<impl IntoResponse, AppError> {
    let record = readable_campaign(&state, &reader, id).await?;
    let campaign = campaigns::decode(&record)?;
    let mut batch_list = Vec::new();
    for (index, batch_id) in record.batch_ids.iter().enumerate() {
        let Some(status) = state.db.batch_status(*batch_id).await? else {
            continue;
        };
        let stage = campaign
            .batches
            .get(index)
            .map_or_else(|| "unknown".to_owned(), |b| campaigns::stage_id(b.stage));
        batch_list.push(CampaignBatch {
            index: index as u64,
            stage,
            batch_id: *batch_id,
            state: status.summary.state,
            percent_done: status.summary.percent_done,
        });
    }
    let stage_percent_done = campaign
        .outstanding()
        .and_then(|i| batch_list.get(i))
        .map(|b| b.percent_done);
    let reason = match &campaign.status {
        repose_campaign::Status::NeedsAttention { reason } => Some(reason.clone()),
        _ => None,
    };
    Ok(Json(CampaignView {
        summary: campaign_summary(&record),
        reason,
        stage_percent_done,
        batch_list,
        decisions: campaign
            .decisions
            .iter()
            .map(|d| CampaignDecision {
                stage: campaigns::stage_id(d.stage),
                round: d.round,
                text: d.text.clone(),
            })
            .collect(),
        result: campaign
            .summary
            .as_ref()
            .and_then(|summary| serde_json::to_value(summary).ok()),
    }))
}

/// The campaign report: a self-contained HTML page, or `?format=json`.
pub(super) async fn campaign_report(
    State(state): State<AppState>,
    reader: Reader,
    PathId(id): PathId,
    Query(query): Query<FormatQuery>,
) -> Result<Response, AppError> {
    let record = readable_campaign(&state, &reader, id).await?;
    let campaign = campaigns::decode(&record)?;
    let results = campaigns::stage_results(&state, &record).await?;
    let pictures = campaigns::report_pictures(&state, &campaign, &record).await?;
    match query.format.as_deref() {
        Some("json") => Ok(Json(repose_campaign::report_json(&campaign, &results)).into_response()),
        None | Some("html") => {
            let html = tokio::task::spawn_blocking(move || {
                repose_campaign::report_html(&campaign, &results, &pictures)
            })
            .await
            .map_err(|err| AppError::Internal(format!("report task: {err}")))?;
            Ok(([(header::CONTENT_TYPE, "text/html; charset=utf-8")], html).into_response())
        }
        Some(other) => Err(AppError::BadRequest(format!(
            "unknown format `{other}` (expected html or json)"
        ))),
    }
}

/// Campaign `id` if it exists and `reader` may read it (404 otherwise, as for a missing one).
async fn readable_campaign(
    state: &AppState,
    reader: &Reader,
    id: uuid::Uuid,
) -> Result<crate::db::CampaignRecord, AppError> {
    let record = state
        .db
        .campaign(id)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("campaign {id} not found")))?;
    check_owner(
        state,
        reader,
        record.owner.as_deref(),
        &format!("campaign {id}"),
    )?;
    Ok(record)
}
