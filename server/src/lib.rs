//! The job server (axum + SQLite). Not built yet: see the job-server issue.
