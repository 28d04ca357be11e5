//! Access tokens (only their hashes are stored).

use super::*;

impl Db {
    /// Stores a new token; `false` (and nothing stored) when the name is taken.
    pub async fn insert_token(
        &self,
        name: &str,
        role: TokenRole,
        hash: &str,
    ) -> Result<bool, sqlx::Error> {
        let inserted = sqlx::query(
            "INSERT INTO tokens (id, name, role, hash, created_at) VALUES (?, ?, ?, ?, ?)
             ON CONFLICT (name) DO NOTHING",
        )
        .bind(Uuid::new_v4().to_string())
        .bind(name)
        .bind(role.as_str())
        .bind(hash)
        .bind(now_ms())
        .execute(&self.writer)
        .await?
        .rows_affected();
        Ok(inserted == 1)
    }

    /// Every token, oldest first (revoked ones included).
    pub async fn list_tokens(&self) -> Result<Vec<TokenInfo>, sqlx::Error> {
        let rows = sqlx::query(
            "SELECT name, role, created_at, revoked_at FROM tokens ORDER BY created_at, rowid",
        )
        .fetch_all(&self.reader)
        .await?;
        rows.iter().map(token_from_row).collect()
    }

    /// The token with SHA-256 `hash`, revoked or not.
    pub async fn find_token(&self, hash: &str) -> Result<Option<TokenInfo>, sqlx::Error> {
        let row =
            sqlx::query("SELECT name, role, created_at, revoked_at FROM tokens WHERE hash = ?")
                .bind(hash)
                .fetch_optional(&self.reader)
                .await?;
        row.as_ref().map(token_from_row).transpose()
    }

    /// Revokes the token `name` (a no-op if it already is); `None` if there is no such token.
    pub async fn revoke_token(&self, name: &str) -> Result<Option<TokenInfo>, sqlx::Error> {
        let row = sqlx::query(
            "UPDATE tokens SET revoked_at = COALESCE(revoked_at, ?) WHERE name = ?
             RETURNING name, role, created_at, revoked_at",
        )
        .bind(now_ms())
        .bind(name)
        .fetch_optional(&self.writer)
        .await?;
        row.as_ref().map(token_from_row).transpose()
    }
}

pub(super) fn token_from_row(row: &SqliteRow) -> Result<TokenInfo, sqlx::Error> {
    let role: String = row.try_get("role")?;
    Ok(TokenInfo {
        name: row.try_get("name")?,
        role: role
            .parse()
            .map_err(|err| sqlx::Error::Decode(Box::new(err)))?,
        created_at_ms: row.try_get("created_at")?,
        revoked_at_ms: row.try_get("revoked_at")?,
    })
}
