//! Access control: bearer tokens with a role, checked by one middleware for every endpoint.
//!
//! Each endpoint of the route table ([`crate::routes::ENDPOINTS`]) names its [`Access`];
//! [`authorize`] enforces it before the handler runs and leaves the authenticated [`Caller`]
//! in the request for handlers that need to know who asks (batch ownership).
//!
//! | access | who passes |
//! | --- | --- |
//! | [`Access::Public`] | everyone (`/healthz`, `/openapi.json`) |
//! | [`Access::Read`] | any valid token (user or worker); anyone when `open_read` is set |
//! | [`Access::User`] | a user token; a worker token gets 403 |
//! | [`Access::Worker`] | a worker token; a user token gets 403 |
//!
//! A missing, malformed, unknown or revoked token is 401 with `WWW-Authenticate: Bearer`.
//!
//! The status page's sign-in stores a token in the [`SESSION_COOKIE`] (HttpOnly,
//! SameSite=Strict). That cookie stands for the token on [`Access::Read`] endpoints only, so
//! the page's links (campaign reports, analyses) work in a browser; an endpoint that changes
//! state never accepts it, and a forged cross-site form can therefore never act with it.
//!
//! With [`crate::Config::private_reads`], reads are narrowed further: no anonymous reads, a
//! worker token reads only `GET /v1/jobs` (its own workers' jobs), and a user token reads only
//! its own batches and campaigns (the handlers check ownership; lists are filtered).

use axum::extract::{FromRequestParts, Request, State};
use axum::http::request::Parts;
use axum::http::{header, HeaderMap};
use axum::middleware::Next;
use axum::response::Response;
use rand::RngCore;
use sha2::{Digest, Sha256};

use crate::error::AppError;
pub use crate::types::{TokenRole, UnknownRole};
use crate::AppState;

/// Who may call an endpoint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// No token needed.
    Public,
    /// Any valid token; anonymous too when the server runs with `open_read`.
    Read,
    /// A user (API) token.
    User,
    /// A worker token.
    Worker,
}

/// The authenticated sender of a request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Caller {
    /// Token name (the owner recorded on submitted batches).
    pub name: String,
    /// Token role.
    pub role: TokenRole,
}

/// Name of the cookie in which the status page's sign-in keeps the token.
pub const SESSION_COOKIE: &str = "repose_token";

/// Random hex digits after the role prefix.
const SECRET_HEX_DIGITS: usize = 32;

/// A fresh secret token text for `role`: `rp_<role>_<32 hex digits>` (128 random bits).
pub fn new_secret(role: TokenRole) -> String {
    let mut bytes = [0u8; SECRET_HEX_DIGITS / 2];
    rand::rngs::OsRng.fill_bytes(&mut bytes);
    format!("rp_{}_{}", role.as_str(), hex(&bytes))
}

/// The stored form of a secret: lower-case hex SHA-256 of its text.
pub fn hash_secret(secret: &str) -> String {
    hex(&Sha256::digest(secret.as_bytes()))
}

/// Whether `text` has the shape of a token (prefix, role, 32 lower-case hex digits); lets
/// obvious garbage be refused without a database look-up.
fn well_formed(text: &str) -> bool {
    let rest = text
        .strip_prefix("rp_user_")
        .or_else(|| text.strip_prefix("rp_worker_"));
    rest.is_some_and(|digits| {
        digits.len() == SECRET_HEX_DIGITS
            && digits
                .bytes()
                .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
    })
}

fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write as _;
    let mut out = String::with_capacity(bytes.len() * 2);
    for byte in bytes {
        let _ = write!(out, "{byte:02x}");
    }
    out
}

/// The token of an `Authorization: Bearer <token>` header; `Ok(None)` when there is no header.
pub(crate) fn bearer(headers: &HeaderMap) -> Result<Option<&str>, AppError> {
    let Some(value) = headers.get(header::AUTHORIZATION) else {
        return Ok(None);
    };
    let text = value
        .to_str()
        .map_err(|_| AppError::Unauthorized("malformed Authorization header".into()))?;
    let (scheme, token) = text.split_once(' ').unwrap_or((text, ""));
    if !scheme.eq_ignore_ascii_case("bearer") {
        return Err(AppError::Unauthorized(
            "the Authorization header must be `Bearer <token>`".into(),
        ));
    }
    Ok(Some(token.trim()))
}

/// The value of the [`SESSION_COOKIE`] among the request's `Cookie` headers, if any.
pub(crate) fn cookie_token(headers: &HeaderMap) -> Option<&str> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|value| value.to_str().ok())
        .flat_map(|value| value.split(';'))
        .filter_map(|pair| pair.trim().split_once('='))
        .find(|(name, _)| *name == SESSION_COOKIE)
        .map(|(_, value)| value.trim())
}

/// Who may read the status page, decided by the same rules as the API's reads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum PageReader {
    /// May read: the token's caller, or `None` for an anonymous reader under `open_read`.
    Allowed(Option<Caller>),
    /// Must sign in first, for this reason.
    SignIn(SignInReason),
}

/// Why the status page asks for a token instead of showing the server.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum SignInReason {
    /// No token was presented and the server does not allow anonymous reads.
    NoToken,
    /// The token presented (typed in, or kept in the cookie) is malformed, unknown or revoked.
    Refused,
    /// A worker token, on a server with private reads (worker tokens read only their jobs).
    WorkerToken,
}

/// Decides what the holder of `token` (or nobody, `None`) may see on the status page.
/// Refusals are outcomes, not errors; only a failing database is an error.
pub(crate) async fn page_reader(
    state: &AppState,
    token: Option<&str>,
) -> Result<PageReader, AppError> {
    let Some(token) = token else {
        return Ok(if state.config.open_read && !state.config.private_reads {
            PageReader::Allowed(None)
        } else {
            PageReader::SignIn(SignInReason::NoToken)
        });
    };
    match authenticate(state, token).await {
        Ok(caller) if state.config.private_reads && caller.role == TokenRole::Worker => {
            Ok(PageReader::SignIn(SignInReason::WorkerToken))
        }
        Ok(caller) => Ok(PageReader::Allowed(Some(caller))),
        Err(AppError::Unauthorized(_)) => Ok(PageReader::SignIn(SignInReason::Refused)),
        Err(other) => Err(other),
    }
}

/// Looks up the presented token: 401 unless it exists and is not revoked.
async fn authenticate(state: &AppState, token: &str) -> Result<Caller, AppError> {
    if !well_formed(token) {
        return Err(AppError::Unauthorized(
            "invalid token (expected rp_user_… or rp_worker_…)".into(),
        ));
    }
    let Some(found) = state.db.find_token(&hash_secret(token)).await? else {
        return Err(AppError::Unauthorized("unknown token".into()));
    };
    if found.revoked_at_ms.is_some() {
        return Err(AppError::Unauthorized(format!(
            "token `{}` was revoked",
            found.name
        )));
    }
    Ok(Caller {
        name: found.name,
        role: found.role,
    })
}

/// The one access check: enforces `access` for the request and stores the [`Caller`] in its
/// extensions. Installed by the route table on every endpoint.
pub async fn authorize(
    State((state, access)): State<(AppState, Access)>,
    mut request: Request,
    next: Next,
) -> Result<Response, AppError> {
    if access == Access::Public {
        return Ok(next.run(request).await);
    }
    let presented = match bearer(request.headers())? {
        Some(token) => Some(token.to_owned()),
        // The sign-in cookie stands for its token on reads only (see the module docs).
        None if access == Access::Read => cookie_token(request.headers()).map(str::to_owned),
        None => None,
    };
    let caller = match presented {
        Some(token) => Some(authenticate(&state, &token).await?),
        None => None,
    };
    match (access, &caller) {
        (Access::Read, None) if state.config.open_read && !state.config.private_reads => {}
        (Access::Read, Some(c))
            if state.config.private_reads
                && c.role == TokenRole::Worker
                && request.uri().path() != "/v1/jobs" =>
        {
            return Err(AppError::Forbidden(format!(
                "token `{}` is a worker token; with private reads a worker token reads only \
                 its jobs (GET /v1/jobs)",
                c.name
            )))
        }
        (_, None) => {
            return Err(AppError::Unauthorized(
                "this endpoint needs a token: send `Authorization: Bearer <token>`".into(),
            ))
        }
        (Access::User, Some(c)) if c.role != TokenRole::User => {
            return Err(AppError::Forbidden(format!(
                "token `{}` is a {} token; this endpoint needs a user token",
                c.name, c.role
            )))
        }
        (Access::Worker, Some(c)) if c.role != TokenRole::Worker => {
            return Err(AppError::Forbidden(format!(
                "token `{}` is a {} token; this endpoint needs a worker token",
                c.name, c.role
            )))
        }
        _ => {}
    }
    if let Some(caller) = caller {
        request.extensions_mut().insert(caller);
    }
    Ok(next.run(request).await)
}

impl<S: Send + Sync> FromRequestParts<S> for Caller {
    type Rejection = AppError;

    /// The caller [`authorize`] authenticated; only endpoints that require a token use this.
    async fn from_request_parts(parts: &mut Parts, _state: &S) -> Result<Self, AppError> {
        parts
            .extensions
            .get::<Caller>()
            .cloned()
            .ok_or_else(|| AppError::Internal("handler needs a caller but none was set".into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn secrets_are_well_formed_distinct_and_hash_to_hex() {
        let user = new_secret(TokenRole::User);
        let worker = new_secret(TokenRole::Worker);
        assert!(
            user.starts_with("rp_user_") && user.len() == 8 + 32,
            "{user}"
        );
        assert!(worker.starts_with("rp_worker_") && worker.len() == 10 + 32);
        assert!(well_formed(&user) && well_formed(&worker));
        assert_ne!(user, new_secret(TokenRole::User));
        let hash = hash_secret(&user);
        assert_eq!(hash.len(), 64);
        assert_ne!(hash, hash_secret(&worker));
        // SHA-256 of "abc" (FIPS 180-2 example).
        assert_eq!(
            hash_secret("abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn malformed_tokens_are_recognised() {
        for bad in [
            "",
            "rp_user_",
            "rp_admin_0123456789abcdef0123456789abcdef",
            "rp_user_0123456789ABCDEF0123456789abcdef",
            "rp_user_0123456789abcdef0123456789abcde",
            "rp_user_0123456789abcdef0123456789abcdef0",
        ] {
            assert!(!well_formed(bad), "{bad}");
        }
    }

    #[test]
    fn the_session_cookie_is_found_among_others() {
        let mut headers = HeaderMap::new();
        assert_eq!(cookie_token(&headers), None);
        headers.append(header::COOKIE, "theme=dark; other=1".parse().unwrap());
        assert_eq!(cookie_token(&headers), None);
        headers.append(
            header::COOKIE,
            "a=b; repose_token=rp_user_x ;c=d".parse().unwrap(),
        );
        assert_eq!(cookie_token(&headers), Some("rp_user_x"));
    }

    #[test]
    fn roles_round_trip() {
        for role in [TokenRole::User, TokenRole::Worker] {
            assert_eq!(role.as_str().parse::<TokenRole>(), Ok(role));
        }
        assert!("admin".parse::<TokenRole>().is_err());
    }
}
