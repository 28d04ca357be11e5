//! Analysis inputs and stored analyses.

use super::*;

/// What the analysis needs to know about a batch.
#[derive(Debug, Clone)]
pub struct AnalysisInput {
    /// Batch id.
    pub batch_id: Uuid,
    /// Life cycle state.
    pub state: BatchState,
    /// Factors in column order.
    pub factors: Vec<Factor>,
    /// How the design was built.
    pub design_kind: DesignKind,
    /// Response metric.
    pub response: String,
    /// Model family.
    pub model: ModelName,
    /// Target response, if any.
    pub target: Option<f64>,
    /// Base seed (reused for the optimum search).
    pub base_seed: u64,
    /// Coded settings and metrics of every completed run.
    pub completed: Vec<(Vec<f64>, BTreeMap<String, f64>)>,
}

impl Db {
    /// The inputs of a batch's analysis, or `None` if the batch does not exist.
    pub async fn analysis_input(&self, batch_id: Uuid) -> Result<Option<AnalysisInput>, DbError> {
        let Some(batch) = sqlx::query(
            "SELECT state, factors, design_kind, response, model, target, base_seed
             FROM batches WHERE id = ?",
        )
        .bind(batch_id.to_string())
        .fetch_optional(&self.reader)
        .await?
        else {
            return Ok(None);
        };
        let rows = sqlx::query(
            "SELECT coded, metrics FROM runs
             WHERE batch_id = ? AND metrics IS NOT NULL ORDER BY run_index",
        )
        .bind(batch_id.to_string())
        .fetch_all(&self.reader)
        .await?;
        let completed = rows
            .iter()
            .map(
                |row| -> Result<(Vec<f64>, BTreeMap<String, f64>), DbError> {
                    let coded: Vec<f64> = serde_json::from_str(row.try_get("coded")?)?;
                    let metrics: BTreeMap<String, f64> =
                        serde_json::from_str(row.try_get("metrics")?)?;
                    Ok((coded, metrics))
                },
            )
            .collect::<Result<Vec<_>, DbError>>()?;
        Ok(Some(AnalysisInput {
            batch_id,
            state: batch_state_from_db(batch.try_get("state")?)?,
            factors: serde_json::from_str(batch.try_get("factors")?)?,
            design_kind: serde_json::from_str(batch.try_get("design_kind")?)?,
            response: batch.try_get("response")?,
            model: model_from_db(batch.try_get("model")?)?,
            target: batch.try_get("target")?,
            base_seed: batch.try_get::<i64, _>("base_seed")? as u64,
            completed,
        }))
    }

    /// The stored analysis of a batch, if computed.
    pub async fn analysis(&self, batch_id: Uuid) -> Result<Option<AnalysisView>, DbError> {
        let stored: Option<String> =
            sqlx::query_scalar("SELECT result FROM analyses WHERE batch_id = ?")
                .bind(batch_id.to_string())
                .fetch_optional(&self.reader)
                .await?;
        Ok(stored.map(|s| serde_json::from_str(&s)).transpose()?)
    }

    /// Stores an analysis unless one exists, and returns the stored one: whoever computed
    /// first wins, so every reader sees the same result.
    pub async fn store_analysis(&self, analysis: &AnalysisView) -> Result<AnalysisView, DbError> {
        let mut tx = self.begin_write().await?;
        let result: Result<AnalysisView, DbError> = async {
            sqlx::query(
                "INSERT INTO analyses (batch_id, computed_at, result) VALUES (?, ?, ?)
                 ON CONFLICT (batch_id) DO NOTHING",
            )
            .bind(analysis.batch_id.to_string())
            .bind(analysis.computed_at_ms)
            .bind(serde_json::to_string(analysis)?)
            .execute(&mut *tx)
            .await?;
            let stored: String =
                sqlx::query_scalar("SELECT result FROM analyses WHERE batch_id = ?")
                    .bind(analysis.batch_id.to_string())
                    .fetch_one(&mut *tx)
                    .await?;
            Ok(serde_json::from_str(&stored)?)
        }
        .await;
        tx.finish(result).await
    }
}
