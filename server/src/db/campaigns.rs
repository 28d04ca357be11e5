//! Campaigns: the chain of batches is written here; decisions are made by `repose-campaign`.

use super::*;

/// A stored campaign.
#[derive(Debug, Clone)]
pub struct CampaignRecord {
    pub id: Uuid,
    pub name: String,
    pub owner: Option<String>,
    pub status: String,
    pub stage: String,
    /// The `repose_campaign::Campaign` document.
    pub state: String,
    pub batches_issued: i64,
    pub created_at_ms: i64,
    pub updated_at_ms: i64,
    /// Batch ids in issue order.
    pub batch_ids: Vec<Uuid>,
    /// Whether one of its batches is an active `gpu` batch.
    pub gpu_batches_active: bool,
    /// Set while one of its batches waits for a GPU worker and none was seen lately.
    pub gpu_wait: Option<GpuWait>,
}

/// What a campaign advance writes.
#[derive(Debug)]
pub struct CampaignUpdate<'a> {
    pub status: &'a str,
    pub stage: &'a str,
    pub state: String,
    /// The next batches to issue (none, one, or a whole round submitted together).
    pub next: &'a [PlannedBatch],
}

// Campaigns: the chain of batches is written here; decisions are made by `repose-campaign`.
impl Db {
    /// Stores a new campaign with its first batches, in one transaction; returns their ids.
    pub async fn insert_campaign(
        &self,
        id: Uuid,
        name: &str,
        owner: &str,
        update: CampaignUpdate<'_>,
    ) -> Result<Vec<Uuid>, DbError> {
        let now = now_ms();
        if update.next.is_empty() {
            return Err(DbError::Corrupt("a campaign starts with a batch".into()));
        }
        let mut tx = self.begin_write().await?;
        let result: Result<Vec<Uuid>, DbError> = async {
            sqlx::query(
                "INSERT INTO campaigns (id, name, owner, status, stage, state, batches_issued,
                                        created_at, updated_at)
                 VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            )
            .bind(id.to_string())
            .bind(name)
            .bind(owner)
            .bind(update.status)
            .bind(update.stage)
            .bind(&update.state)
            .bind(update.next.len() as i64)
            .bind(now)
            .bind(now)
            .execute(&mut *tx)
            .await?;
            let mut ids = Vec::with_capacity(update.next.len());
            for (index, plan) in update.next.iter().enumerate() {
                let batch_id = insert_batch_tx(&mut tx, plan, owner).await?;
                link_batch(&mut tx, batch_id, id, index as i64).await?;
                ids.push(batch_id);
            }
            Ok(ids)
        }
        .await;
        tx.finish(result).await
    }

    /// Records a campaign step if nobody advanced it since it was read (`issued_before`
    /// batches issued and the stored document still `state_before`); `Ok(None)` when someone
    /// did (nothing written). Returns the new batches' ids (none when nothing is issued).
    pub async fn advance_campaign(
        &self,
        id: Uuid,
        issued_before: i64,
        state_before: &str,
        owner: Option<&str>,
        update: CampaignUpdate<'_>,
    ) -> Result<Option<Vec<Uuid>>, DbError> {
        let now = now_ms();
        let mut tx = self.begin_write().await?;
        let result: Result<Option<Vec<Uuid>>, DbError> = async {
            let issued_after = issued_before + update.next.len() as i64;
            let changed = sqlx::query(
                "UPDATE campaigns SET status = ?, stage = ?, state = ?, batches_issued = ?,
                                      updated_at = ?
                 WHERE id = ? AND batches_issued = ? AND state = ?",
            )
            .bind(update.status)
            .bind(update.stage)
            .bind(&update.state)
            .bind(issued_after)
            .bind(now)
            .bind(id.to_string())
            .bind(issued_before)
            .bind(state_before)
            .execute(&mut *tx)
            .await?
            .rows_affected();
            if changed != 1 {
                return Ok(None);
            }
            let mut ids = Vec::with_capacity(update.next.len());
            for (i, plan) in update.next.iter().enumerate() {
                let batch_id = insert_batch_tx(&mut tx, plan, owner.unwrap_or("")).await?;
                link_batch(&mut tx, batch_id, id, issued_before + i as i64).await?;
                ids.push(batch_id);
            }
            Ok(Some(ids))
        }
        .await;
        tx.finish(result).await
    }

    /// The campaign a batch belongs to and the batch's position in it.
    pub async fn campaign_of_batch(&self, batch_id: Uuid) -> Result<Option<(Uuid, i64)>, DbError> {
        let row = sqlx::query(
            "SELECT campaign_id, campaign_index FROM batches
             WHERE id = ? AND campaign_id IS NOT NULL",
        )
        .bind(batch_id.to_string())
        .fetch_optional(&self.reader)
        .await?;
        row.map(|row| -> Result<(Uuid, i64), DbError> {
            Ok((
                parse_uuid(&row.try_get::<String, _>("campaign_id")?)?,
                row.try_get("campaign_index")?,
            ))
        })
        .transpose()
    }

    /// One campaign with its batch ids.
    pub async fn campaign(&self, id: Uuid) -> Result<Option<CampaignRecord>, DbError> {
        let Some(row) = sqlx::query(&format!("{CAMPAIGN_SELECT} WHERE id = ?"))
            .bind(id.to_string())
            .fetch_optional(&self.reader)
            .await?
        else {
            return Ok(None);
        };
        let batch_rows =
            sqlx::query("SELECT id FROM batches WHERE campaign_id = ? ORDER BY campaign_index")
                .bind(id.to_string())
                .fetch_all(&self.reader)
                .await?;
        let batch_ids = batch_rows
            .iter()
            .map(|r| parse_uuid(&r.try_get::<String, _>("id")?))
            .collect::<Result<Vec<_>, DbError>>()?;
        let mut record = campaign_from_row(&row, batch_ids)?;
        self.flag_gpu_waits_of(std::slice::from_mut(&mut record))
            .await?;
        Ok(Some(record))
    }

    /// The newest campaigns (without their batch ids), newest first; only `owner`'s if given.
    pub async fn list_campaigns(
        &self,
        limit: u32,
        owner: Option<&str>,
    ) -> Result<Vec<CampaignRecord>, DbError> {
        let rows = sqlx::query(&format!(
            "{CAMPAIGN_SELECT} WHERE (?1 IS NULL OR owner = ?1)
             ORDER BY created_at DESC LIMIT ?2"
        ))
        .bind(owner)
        .bind(i64::from(limit))
        .fetch_all(&self.reader)
        .await?;
        let mut records = rows
            .iter()
            .map(|row| campaign_from_row(row, Vec::new()))
            .collect::<Result<Vec<_>, _>>()?;
        self.flag_gpu_waits_of(&mut records).await?;
        Ok(records)
    }

    /// Sets `gpu_wait` on the campaigns among `records` with an active `gpu` batch while no
    /// worker with a GPU was seen lately ([`Db::gpu_wait`]).
    async fn flag_gpu_waits_of(&self, records: &mut [CampaignRecord]) -> Result<(), DbError> {
        if !records.iter().any(|r| r.gpu_batches_active) {
            return Ok(());
        }
        let wait = self.gpu_wait().await?;
        for record in records.iter_mut().filter(|r| r.gpu_batches_active) {
            record.gpu_wait = wait;
        }
        Ok(())
    }

    /// Ids of the campaigns still running (resumed at start-up).
    pub async fn running_campaigns(&self) -> Result<Vec<Uuid>, DbError> {
        let rows = sqlx::query("SELECT id FROM campaigns WHERE status = 'running'")
            .fetch_all(&self.reader)
            .await?;
        rows.iter()
            .map(|r| parse_uuid(&r.try_get::<String, _>("id")?))
            .collect()
    }
}

pub(super) async fn link_batch(
    tx: &mut WriteTx,
    batch_id: Uuid,
    campaign_id: Uuid,
    index: i64,
) -> Result<(), DbError> {
    sqlx::query("UPDATE batches SET campaign_id = ?, campaign_index = ? WHERE id = ?")
        .bind(campaign_id.to_string())
        .bind(index)
        .bind(batch_id.to_string())
        .execute(&mut **tx)
        .await?;
    Ok(())
}

/// A campaign's row, and whether it has an active `gpu` batch.
const CAMPAIGN_SELECT: &str = "SELECT *, EXISTS (SELECT 1 FROM batches b
        WHERE b.campaign_id = campaigns.id AND b.state = 'active' AND b.backend = 'gpu')
        AS gpu_batches_active
    FROM campaigns";

pub(super) fn campaign_from_row(
    row: &SqliteRow,
    batch_ids: Vec<Uuid>,
) -> Result<CampaignRecord, DbError> {
    Ok(CampaignRecord {
        id: parse_uuid(&row.try_get::<String, _>("id")?)?,
        name: row.try_get("name")?,
        owner: row.try_get("owner")?,
        status: row.try_get("status")?,
        stage: row.try_get("stage")?,
        state: row.try_get("state")?,
        batches_issued: row.try_get("batches_issued")?,
        created_at_ms: row.try_get("created_at")?,
        updated_at_ms: row.try_get("updated_at")?,
        batch_ids,
        gpu_batches_active: row.try_get("gpu_batches_active")?,
        gpu_wait: None,
    })
}
