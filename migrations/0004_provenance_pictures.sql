-- Provenance and pictures: the engine version that computed each result, and the pictures of
-- runs in batches that ask to keep them (a campaign's verification and drilling batches).

ALTER TABLE runs ADD COLUMN engine_version TEXT;
-- JSON object: file name -> SVG text. NULL unless the batch keeps pictures.
ALTER TABLE runs ADD COLUMN pictures TEXT;
ALTER TABLE batches ADD COLUMN keep_pictures INTEGER NOT NULL DEFAULT 0;
