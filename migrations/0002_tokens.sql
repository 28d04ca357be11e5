-- Access control. A token's secret (`rp_user_<32 hex>` or `rp_worker_<32 hex>`) is shown once
-- at creation; only its SHA-256 (lower-case hex of the whole text) is stored.

CREATE TABLE tokens (
    id            TEXT PRIMARY KEY NOT NULL,
    name          TEXT NOT NULL UNIQUE,       -- kept after revocation: batches name their owner
    role          TEXT NOT NULL CHECK (role IN ('user', 'worker')),
    hash          TEXT NOT NULL UNIQUE,       -- hex SHA-256 of the secret
    created_at    INTEGER NOT NULL,
    revoked_at    INTEGER                     -- NULL while valid
);

-- Name of the user token that submitted the batch; NULL for batches from before access control.
ALTER TABLE batches ADD COLUMN owner TEXT;
