//! Token administration for the command line (`repose token …`) and for embedding programs
//! (`repose up`): each call opens (creating and migrating if needed) the database file, does
//! one thing and closes it, so it works whether or not a server is running on the same file.

use std::path::Path;

use crate::auth::{hash_secret, new_secret, TokenRole};
use crate::db::Db;
pub use crate::types::TokenInfo;
use crate::ServeError;

/// Longest accepted token name.
pub const MAX_NAME_LEN: usize = 64;

/// Checks a token name: 1..=64 characters out of letters, digits, `-`, `_`, `.` and `@`.
pub fn validate_name(name: &str) -> Result<(), ServeError> {
    let reason = if name.is_empty() {
        "must not be empty"
    } else if name.chars().count() > MAX_NAME_LEN {
        "must be at most 64 characters"
    } else if !name
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.' | '@'))
    {
        "may contain only letters, digits, '-', '_', '.' and '@'"
    } else {
        return Ok(());
    };
    Err(ServeError::InvalidTokenName {
        name: name.to_owned(),
        reason,
    })
}

/// Creates a token called `name` with `role` in the database at `db_path` and returns its
/// secret text (`rp_user_…` / `rp_worker_…`). The secret is not stored (only its SHA-256), so
/// this is the only time it is available. Names are unique, revoked tokens included.
pub async fn create_token(
    db_path: &Path,
    name: &str,
    role: TokenRole,
) -> Result<String, ServeError> {
    validate_name(name)?;
    let db = Db::open(db_path).await?;
    let secret = new_secret(role);
    let inserted = db.insert_token(name, role, &hash_secret(&secret)).await;
    db.close().await;
    if inserted? {
        Ok(secret)
    } else {
        Err(ServeError::TokenNameTaken(name.to_owned()))
    }
}

/// The token whose secret text is `secret`, revoked or not, if the database at `db_path`
/// holds it (found by the secret's hash).
pub async fn find_secret(db_path: &Path, secret: &str) -> Result<Option<TokenInfo>, ServeError> {
    let db = Db::open(db_path).await?;
    let found = db.find_token(&hash_secret(secret)).await;
    db.close().await;
    Ok(found?)
}

/// Every token of the database at `db_path`, oldest first, revoked ones included.
pub async fn list_tokens(db_path: &Path) -> Result<Vec<TokenInfo>, ServeError> {
    let db = Db::open(db_path).await?;
    let tokens = db.list_tokens().await;
    db.close().await;
    Ok(tokens?)
}

/// Revokes the token `name`: requests presenting it get 401 from then on (a running server
/// sees the change at its next request). Revoking a revoked token changes nothing.
pub async fn revoke_token(db_path: &Path, name: &str) -> Result<TokenInfo, ServeError> {
    let db = Db::open(db_path).await?;
    let revoked = db.revoke_token(name).await;
    db.close().await;
    revoked?.ok_or_else(|| ServeError::TokenNotFound(name.to_owned()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_checked() {
        for good in ["alice", "lab-pc_2", "a.b@c", &"x".repeat(64)] {
            assert!(validate_name(good).is_ok(), "{good}");
        }
        for bad in ["", "has space", "semi;colon", "é", &"x".repeat(65)] {
            assert!(validate_name(bad).is_err(), "{bad}");
        }
    }

    #[tokio::test]
    async fn create_list_revoke_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.sqlite");
        let secret = create_token(&path, "alice", TokenRole::User).await.unwrap();
        assert!(secret.starts_with("rp_user_"));
        let worker = create_token(&path, "w1", TokenRole::Worker).await.unwrap();
        assert!(worker.starts_with("rp_worker_"));
        assert!(matches!(
            create_token(&path, "alice", TokenRole::Worker).await,
            Err(ServeError::TokenNameTaken(name)) if name == "alice"
        ));
        let listed = list_tokens(&path).await.unwrap();
        assert_eq!(listed.len(), 2);
        assert_eq!(listed[0].name, "alice");
        assert_eq!(listed[0].role, TokenRole::User);
        assert_eq!(listed[1].role, TokenRole::Worker);
        assert!(listed.iter().all(|t| t.revoked_at_ms.is_none()));

        let revoked = revoke_token(&path, "alice").await.unwrap();
        assert!(revoked.revoked_at_ms.is_some());
        let again = revoke_token(&path, "alice").await.unwrap();
        assert_eq!(again.revoked_at_ms, revoked.revoked_at_ms, "idempotent");
        assert!(matches!(
            revoke_token(&path, "bob").await,
            Err(ServeError::TokenNotFound(name)) if name == "bob"
        ));
        // The secret itself is stored nowhere in the database file.
        let bytes = std::fs::read(&path).unwrap();
        let text = String::from_utf8_lossy(&bytes);
        assert!(!text.contains(&secret[8..]));
    }
}
