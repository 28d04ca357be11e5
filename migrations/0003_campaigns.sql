-- Calibration campaigns: a chain of batches, each generated from the previous one's results.
-- `state` is the repose-campaign `Campaign` document (JSON); `batches_issued` guards against two
-- concurrent advances of the same campaign (the update expects the count it read).

CREATE TABLE campaigns (
    id              TEXT PRIMARY KEY NOT NULL,
    name            TEXT NOT NULL,
    owner           TEXT,
    status          TEXT NOT NULL CHECK (status IN ('running', 'finished', 'needs_attention')),
    stage           TEXT NOT NULL,
    state           TEXT NOT NULL,
    batches_issued  INTEGER NOT NULL,
    created_at      INTEGER NOT NULL,
    updated_at      INTEGER NOT NULL
);

CREATE INDEX campaigns_created ON campaigns (created_at);

-- Which campaign (and which of its batches, by issue order) a batch belongs to.
ALTER TABLE batches ADD COLUMN campaign_id TEXT REFERENCES campaigns (id);
ALTER TABLE batches ADD COLUMN campaign_index INTEGER;
CREATE INDEX batches_campaign ON batches (campaign_id, campaign_index);
