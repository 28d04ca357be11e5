//! The status page at `/`: its content (progress, time left, workers, dead runs, all user text
//! escaped), and its sign-in: an HttpOnly, SameSite=Strict cookie that then opens the page and
//! the reads it links to, never the writes; wrong, revoked and cross-site sign-ins refused
//! without a cookie and without echoing anything.

use crate::common;

use crate::paper;

use common::{batch_request, temp_db, TestServer};
use repose_api::Failure;
use reqwest::header::{CONTENT_TYPE, COOKIE, LOCATION, ORIGIN, SET_COOKIE};
use reqwest::{Client, StatusCode};
use serde_json::json;

/// A batch name and an error text full of markup, which the page must show as text.
const NASTY_NAME: &str = "<b>sand & \"glass\"</b>";
const NASTY_NAME_ESCAPED: &str = "&lt;b&gt;sand &amp; &quot;glass&quot;&lt;/b&gt;";
const NASTY_ERROR: &str = "heap never settled <script>alert(\"x\")</script> & gave up";
const NASTY_ERROR_ESCAPED: &str =
    "heap never settled &lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; &amp; gave up";

/// A client that shows redirects instead of following them, and keeps no cookies.
fn plain_client() -> Client {
    Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()
        .unwrap()
}

async fn get_page(server: &TestServer, cookie: Option<&str>) -> (StatusCode, String) {
    let mut request = plain_client().get(server.url("/"));
    if let Some(cookie) = cookie {
        request = request.header(COOKIE, cookie);
    }
    let response = request.send().await.unwrap();
    let status = response.status();
    let content_type = response.headers()[CONTENT_TYPE]
        .to_str()
        .unwrap()
        .to_owned();
    assert_eq!(content_type, "text/html; charset=utf-8");
    (status, response.text().await.unwrap())
}

async fn sign_in(server: &TestServer, token: &str) -> reqwest::Response {
    plain_client()
        .post(server.url("/sign-in"))
        .form(&[("token", token)])
        .send()
        .await
        .unwrap()
}

/// Submits a 4-run batch named [`NASTY_NAME`]; one run completes, one dies with
/// [`NASTY_ERROR`], one stays leased by a worker, one stays queued.
async fn batch_in_every_state(server: &TestServer) -> (uuid::Uuid, u32) {
    let mut request = batch_request(json!({"type": "factorial"}), "linear", 1);
    request["name"] = json!(NASTY_NAME);
    let created = server.submit(&request).await;
    assert_eq!(created.run_count, 4);
    let worker = server.register().await;
    let done = server.claim(worker, 1.0).await.unwrap();
    let (status, body) = server.complete(&done).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let doomed = server.claim(worker, 1.0).await.unwrap();
    let failure = Failure {
        lease_token: doomed.lease_token,
        error: NASTY_ERROR.into(),
        permanent: true,
        another_seed: false,
    };
    let (status, body) = server
        .post(
            &format!("/v1/jobs/{}/fail", doomed.job_id),
            &serde_json::to_value(failure).unwrap(),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let held = server.claim(worker, 1.0).await.unwrap();
    let held_index = server
        .runs(created.id)
        .await
        .iter()
        .find(|run| run.id == held.run_id)
        .unwrap()
        .run_index;
    (created.id, held_index)
}

#[tokio::test]
async fn page_shows_progress_workers_and_dead_runs_with_all_text_escaped() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |c| c.open_read = true).await;
    let (status, empty) = get_page(&server, None).await;
    assert_eq!(status, StatusCode::OK);
    assert!(empty.contains("No batches yet."), "{empty}");

    let (batch, held_run) = batch_in_every_state(&server).await;
    let (status, page) = get_page(&server, None).await;
    assert_eq!(status, StatusCode::OK, "{page}");
    // The batch with its progress and time left.
    assert!(page.contains(NASTY_NAME_ESCAPED), "{page}");
    assert!(!page.contains("<b>sand"), "the name was not escaped");
    assert!(
        page.contains("2 of 4 runs finished (50 %), 1 running, "),
        "{page}"
    );
    assert!(page.contains("1 dead"), "{page}");
    assert!(
        page.contains("about "),
        "time left is shown once a run completed"
    );
    assert!(page.contains(&format!("/v1/batches/{batch}/runs?format=csv")));
    // The worker and what it runs (the page names the batch, escaped, and the run).
    assert!(page.contains("test-host"));
    assert!(
        page.contains(&format!("{NASTY_NAME_ESCAPED}, run {held_run}")),
        "{page}"
    );
    // The dead run and its error, as text.
    assert!(page.contains(NASTY_ERROR_ESCAPED), "{page}");
    assert!(!page.contains("<script>"), "the error was not escaped");
    assert!(page.contains("<meta http-equiv=\"refresh\" content=\"15\">"));
    // Anonymous readers get no sign-out button.
    assert!(page.contains("open for reading") && !page.contains("Sign out"));
    server.stop().await;
}

#[tokio::test]
async fn sign_in_sets_a_strict_http_only_cookie_that_opens_the_page_and_reads_only() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let (batch, _) = batch_in_every_state(&server).await;

    // Without a token: the form, and nothing of the server's content.
    let (status, page) = get_page(&server, None).await;
    assert_eq!(status, StatusCode::OK);
    assert!(page.contains("action=\"/sign-in\"") && page.contains("type=\"password\""));
    assert!(!page.contains(NASTY_NAME_ESCAPED) && !page.contains("gave up"));

    let response = sign_in(&server, &server.user_token).await;
    assert_eq!(response.status(), StatusCode::SEE_OTHER);
    assert_eq!(response.headers()[LOCATION], "/");
    let set_cookie = response.headers()[SET_COOKIE].to_str().unwrap().to_owned();
    let attributes: Vec<&str> = set_cookie.split(';').map(str::trim).collect();
    assert_eq!(
        attributes[0],
        format!("repose_token={}", server.user_token),
        "{set_cookie}"
    );
    assert!(attributes.contains(&"HttpOnly"), "{set_cookie}");
    assert!(attributes.contains(&"SameSite=Strict"), "{set_cookie}");
    assert!(attributes.contains(&"Path=/"), "{set_cookie}");
    let cookie = attributes[0].to_owned();

    // The page, read with the cookie.
    let (status, page) = get_page(&server, Some(&cookie)).await;
    assert_eq!(status, StatusCode::OK, "{page}");
    assert!(page.contains(NASTY_NAME_ESCAPED) && page.contains(NASTY_ERROR_ESCAPED));
    assert!(page.contains(&format!("reading as <strong>{}</strong>", server.user_name)));
    assert!(page.contains("Sign out"));

    // The cookie opens the reads the page links to, but no write.
    let csv = plain_client()
        .get(server.url(&format!("/v1/batches/{batch}/runs?format=csv")))
        .header(COOKIE, &cookie)
        .send()
        .await
        .unwrap();
    assert_eq!(csv.status(), StatusCode::OK);
    let cancel = plain_client()
        .post(server.url(&format!("/v1/batches/{batch}/cancel")))
        .header(COOKIE, &cookie)
        .send()
        .await
        .unwrap();
    assert_eq!(cancel.status(), StatusCode::UNAUTHORIZED);
    assert_eq!(
        server.status(batch).await.summary.state,
        repose_api::BatchState::Active
    );

    // Sign-out clears the cookie.
    let response = plain_client()
        .post(server.url("/sign-out"))
        .header(COOKIE, &cookie)
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), StatusCode::SEE_OTHER);
    let cleared = response.headers()[SET_COOKIE].to_str().unwrap();
    assert!(
        cleared.starts_with("repose_token=;") && cleared.contains("Max-Age=0"),
        "{cleared}"
    );
    server.stop().await;
}

#[tokio::test]
async fn wrong_revoked_and_cross_site_sign_ins_are_refused_without_leaking() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    batch_in_every_state(&server).await;
    let unknown = format!("rp_user_{}", "0123456789abcdef".repeat(2));
    for wrong in [
        unknown.as_str(),
        "<i>not-a-token</i>",
        &server.worker_token[..20],
    ] {
        let response = sign_in(&server, wrong).await;
        assert_eq!(response.status(), StatusCode::UNAUTHORIZED, "{wrong}");
        assert!(response.headers().get(SET_COOKIE).is_none(), "{wrong}");
        let page = response.text().await.unwrap();
        assert!(page.contains("was not accepted"), "{page}");
        assert!(
            !page.contains(wrong) && !page.contains("not-a-token"),
            "echoed {wrong}"
        );
        assert!(!page.contains(NASTY_NAME_ESCAPED) && !page.contains("gave up"));
    }

    // A cross-site form post is refused even with a good token.
    let response = plain_client()
        .post(server.url("/sign-in"))
        .header(ORIGIN, "https://elsewhere.example")
        .form(&[("token", server.user_token.as_str())])
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), StatusCode::FORBIDDEN);
    assert!(response.headers().get(SET_COOKIE).is_none());

    // A cookie whose token was revoked: the form again, and the cookie is dropped.
    let cookie = format!("repose_token={}", server.user_token);
    assert_eq!(get_page(&server, Some(&cookie)).await.0, StatusCode::OK);
    repose_server::revoke_token(&db, &server.user_name)
        .await
        .unwrap();
    let response = plain_client()
        .get(server.url("/"))
        .header(COOKIE, &cookie)
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), StatusCode::UNAUTHORIZED);
    let cleared = response.headers()[SET_COOKIE].to_str().unwrap().to_owned();
    assert!(cleared.contains("Max-Age=0"), "{cleared}");
    let page = response.text().await.unwrap();
    assert!(page.contains("was not accepted") && !page.contains(NASTY_NAME_ESCAPED));
    server.stop().await;
}

#[tokio::test]
async fn with_private_reads_the_page_shows_a_user_only_its_own_and_refuses_worker_tokens() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |c| c.private_reads = true).await;
    batch_in_every_state(&server).await;
    let other = repose_server::create_token(&db, "someone-else", repose_server::TokenRole::User)
        .await
        .unwrap();

    let response = sign_in(&server, &other).await;
    assert_eq!(response.status(), StatusCode::SEE_OTHER);
    let (status, page) = get_page(&server, Some(&format!("repose_token={other}"))).await;
    assert_eq!(status, StatusCode::OK);
    assert!(page.contains("No batches yet."), "{page}");
    assert!(!page.contains(NASTY_NAME_ESCAPED) && !page.contains("gave up"));

    let (status, page) = get_page(
        &server,
        Some(&format!("repose_token={}", server.user_token)),
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    assert!(page.contains(NASTY_NAME_ESCAPED) && page.contains(NASTY_ERROR_ESCAPED));

    let response = sign_in(&server, &server.worker_token).await;
    assert_eq!(response.status(), StatusCode::FORBIDDEN);
    assert!(response.headers().get(SET_COOKIE).is_none());
    assert!(response.text().await.unwrap().contains("worker token"));
    server.stop().await;
}

#[tokio::test]
async fn campaigns_are_listed_with_their_stage_and_a_report_the_cookie_opens() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let (status, created) = server
        .post(
            "/v1/campaigns",
            &paper::paper_campaign_json("<u>paper</u> replay"),
        )
        .await;
    assert_eq!(status, StatusCode::CREATED, "{created}");
    let id = created["id"].as_str().unwrap().to_owned();

    let cookie = format!("repose_token={}", server.user_token);
    let (status, page) = get_page(&server, Some(&cookie)).await;
    assert_eq!(status, StatusCode::OK);
    assert!(page.contains("&lt;u&gt;paper&lt;/u&gt; replay"), "{page}");
    assert!(
        !page.contains("<u>paper"),
        "the campaign name was not escaped"
    );
    assert!(
        page.contains(">running<") && page.contains(">screening<"),
        "{page}"
    );
    let report_link = format!("/v1/campaigns/{id}/report");
    assert!(page.contains(&format!("href=\"{report_link}\"")), "{page}");

    let report = plain_client()
        .get(server.url(&report_link))
        .header(COOKIE, &cookie)
        .send()
        .await
        .unwrap();
    assert_eq!(report.status(), StatusCode::OK);
    assert!(report.headers()[CONTENT_TYPE]
        .to_str()
        .unwrap()
        .starts_with("text/html"));
    // Without the cookie the report is closed on this server.
    let closed = plain_client()
        .get(server.url(&report_link))
        .send()
        .await
        .unwrap();
    assert_eq!(closed.status(), StatusCode::UNAUTHORIZED);
    server.stop().await;
}
