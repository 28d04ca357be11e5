//! `repose token create|list|revoke`: access tokens of a job server, administered directly on
//! its SQLite file (works while the server runs; a revocation takes effect at once).

use anyhow::{Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use repose_server::{create_token, list_tokens, revoke_token, TokenInfo, TokenRole};
use serde::Serialize;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct TokenArgs {
    /// SQLite database file of the server (created and migrated if missing).
    #[arg(long, env = "REPOSE_DB", default_value = "repose.db", global = true)]
    pub db: PathBuf,
    #[command(subcommand)]
    pub what: TokenCommand,
}

#[derive(Debug, Subcommand)]
pub enum TokenCommand {
    /// Create a token and print its secret (shown only this once; only a hash is stored).
    Create(CreateArgs),
    /// List tokens (names, roles, creation and revocation times; never secrets).
    List(ListArgs),
    /// Revoke a token: requests presenting it get 401 from now on.
    Revoke(RevokeArgs),
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Role {
    /// People and scripts: submit, read and cancel their own batches.
    User,
    /// Worker processes: register, claim and report jobs.
    Worker,
}

impl From<Role> for TokenRole {
    fn from(role: Role) -> Self {
        match role {
            Role::User => TokenRole::User,
            Role::Worker => TokenRole::Worker,
        }
    }
}

#[derive(Debug, Args)]
pub struct CreateArgs {
    /// Unique name (letters, digits, - _ . @); recorded as the owner of submitted batches.
    pub name: String,
    /// What the token may do.
    #[arg(long, value_enum, default_value_t = Role::User)]
    pub role: Role,
}

#[derive(Debug, Args)]
pub struct ListArgs {
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct RevokeArgs {
    /// Name of the token to revoke.
    pub name: String,
}

#[derive(Debug, Serialize)]
struct Listed<'a> {
    name: &'a str,
    role: &'static str,
    created_at_ms: i64,
    revoked_at_ms: Option<i64>,
}

pub fn run(args: &TokenArgs) -> Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let db = &args.db;
    runtime.block_on(async {
        match &args.what {
            TokenCommand::Create(create) => {
                let secret = create_token(db, &create.name, create.role.into())
                    .await
                    .with_context(|| format!("creating token `{}`", create.name))?;
                // The secret alone on stdout, so `TOKEN=$(repose token create NAME)` works.
                println!("{secret}");
                eprintln!(
                    "created {} token `{}` in {}; the secret above is shown only once",
                    TokenRole::from(create.role),
                    create.name,
                    db.display()
                );
            }
            TokenCommand::List(list) => {
                let tokens = list_tokens(db).await.context("listing tokens")?;
                print_tokens(&tokens, list.json)?;
            }
            TokenCommand::Revoke(revoke) => {
                let token = revoke_token(db, &revoke.name)
                    .await
                    .with_context(|| format!("revoking token `{}`", revoke.name))?;
                eprintln!(
                    "revoked {} token `{}` (at {})",
                    token.role,
                    token.name,
                    token.revoked_at_ms.map(utc).unwrap_or_default()
                );
            }
        }
        Ok(())
    })
}

fn print_tokens(tokens: &[TokenInfo], json: bool) -> Result<()> {
    if json {
        let listed: Vec<Listed<'_>> = tokens
            .iter()
            .map(|t| Listed {
                name: &t.name,
                role: t.role.as_str(),
                created_at_ms: t.created_at_ms,
                revoked_at_ms: t.revoked_at_ms,
            })
            .collect();
        println!("{}", serde_json::to_string_pretty(&listed)?);
        return Ok(());
    }
    let width = tokens
        .iter()
        .map(|t| t.name.len())
        .max()
        .unwrap_or(4)
        .max(4);
    println!(
        "{:<width$}  {:<6}  {:<20}  revoked",
        "name", "role", "created (UTC)"
    );
    for token in tokens {
        println!(
            "{:<width$}  {:<6}  {:<20}  {}",
            token.name,
            token.role.as_str(),
            utc(token.created_at_ms),
            token.revoked_at_ms.map(utc).unwrap_or_else(|| "-".into())
        );
    }
    Ok(())
}

/// Unix milliseconds as `YYYY-MM-DD HH:MM:SS` (UTC).
fn utc(ms: i64) -> String {
    let secs = ms.div_euclid(1000);
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02}",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::utc;

    #[test]
    fn utc_formats_known_instants() {
        assert_eq!(utc(0), "1970-01-01 00:00:00");
        assert_eq!(utc(951_782_400_000), "2000-02-29 00:00:00");
        assert_eq!(utc(1_795_290_000_123), "2026-11-21 19:40:00");
    }
}
