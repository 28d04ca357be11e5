-- Job server schema. Times are Unix milliseconds (INTEGER); JSON documents are TEXT.
-- Ids are lower-case hyphenated UUIDs.

CREATE TABLE batches (
    id            TEXT PRIMARY KEY NOT NULL,
    name          TEXT NOT NULL,
    kind          TEXT NOT NULL,              -- experiment kind (aor, drill, ...)
    request       TEXT NOT NULL,              -- the BatchRequest as submitted (JSON)
    factors       TEXT NOT NULL,              -- [{name, path, low, high}] in column order (JSON)
    design_kind   TEXT NOT NULL,              -- repose_doe DesignKind (JSON), for the analysis region
    response      TEXT NOT NULL,
    model         TEXT NOT NULL,              -- linear | 2fi | quadratic
    target        REAL,
    base_seed     INTEGER NOT NULL,
    state         TEXT NOT NULL CHECK (state IN ('active', 'completed', 'cancelled')),
    created_at    INTEGER NOT NULL,
    finished_at   INTEGER
);

CREATE INDEX batches_created ON batches (created_at);

-- One row per simulation: design point x replicate. The result columns are written once.
CREATE TABLE runs (
    id            TEXT PRIMARY KEY NOT NULL,
    batch_id      TEXT NOT NULL REFERENCES batches (id),
    run_index     INTEGER NOT NULL,
    design_row    INTEGER NOT NULL,
    replicate     INTEGER NOT NULL,
    coded         TEXT NOT NULL,              -- [f64] in factor order (JSON)
    natural       TEXT NOT NULL,              -- [f64] in factor order (JSON)
    seed          INTEGER NOT NULL,           -- u64 stored bit-for-bit as i64
    spec          TEXT NOT NULL,              -- experiment spec with the factor values applied
    metrics       TEXT,                       -- {name: f64} once completed (JSON)
    details       TEXT,
    wall_time_s   REAL,
    worker_id     TEXT,
    completed_at  INTEGER,
    UNIQUE (batch_id, run_index)
);

-- The queue: one job per run. Leases live in `leases`; the current one is mirrored here.
CREATE TABLE jobs (
    id                TEXT PRIMARY KEY NOT NULL,
    run_id            TEXT NOT NULL UNIQUE REFERENCES runs (id),
    batch_id          TEXT NOT NULL REFERENCES batches (id),
    state             TEXT NOT NULL CHECK (state IN ('queued', 'leased', 'completed', 'dead', 'cancelled')),
    attempts          INTEGER NOT NULL DEFAULT 0,
    available_at      INTEGER NOT NULL,
    lease_token       TEXT,
    lease_expires_at  INTEGER,
    worker_id         TEXT,
    progress          REAL,
    last_error        TEXT,
    updated_at        INTEGER NOT NULL
);

-- The claim query: oldest available queued job.
CREATE INDEX jobs_claim ON jobs (state, available_at);
-- Reclaiming expired leases.
CREATE INDEX jobs_lease_expiry ON jobs (state, lease_expires_at);
CREATE INDEX jobs_batch ON jobs (batch_id, state);

-- Every lease ever granted, so a late completion of an expired lease can be told apart from
-- a forged, released or duplicate one.
CREATE TABLE leases (
    token         TEXT PRIMARY KEY NOT NULL,
    job_id        TEXT NOT NULL REFERENCES jobs (id),
    worker_id     TEXT NOT NULL,
    attempt       INTEGER NOT NULL,
    granted_at    INTEGER NOT NULL,
    ended_at      INTEGER,
    -- NULL while current; completed | failed | released | expired | superseded | cancelled
    outcome       TEXT
);

CREATE INDEX leases_job ON leases (job_id);

CREATE TABLE workers (
    id             TEXT PRIMARY KEY NOT NULL,
    host           TEXT NOT NULL,
    threads        INTEGER NOT NULL,
    version        TEXT NOT NULL,
    registered_at  INTEGER NOT NULL,
    last_seen_at   INTEGER NOT NULL
);

-- Computed once when a batch finishes.
CREATE TABLE analyses (
    batch_id      TEXT PRIMARY KEY NOT NULL REFERENCES batches (id),
    computed_at   INTEGER NOT NULL,
    result        TEXT NOT NULL               -- AnalysisView (JSON)
);
