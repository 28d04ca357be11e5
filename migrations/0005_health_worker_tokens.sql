-- The health check's write probe: `GET /healthz` updates this one row through the writer.
CREATE TABLE health (
    id         INTEGER PRIMARY KEY CHECK (id = 1),
    probed_at  INTEGER NOT NULL
);
INSERT INTO health (id, probed_at) VALUES (1, 0);

-- Name of the worker token that registered the worker; only that token may register over,
-- claim for or otherwise act as this worker id. NULL for workers from before this migration
-- (the first token to register them again takes them over).
ALTER TABLE workers ADD COLUMN token TEXT;
