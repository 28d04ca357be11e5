-- The engine a batch's runs need: its request's `experiment.backend` (issue 38). Batches from
-- before this migration ran on the CPU.
ALTER TABLE batches ADD COLUMN backend TEXT NOT NULL DEFAULT 'cpu' CHECK (backend IN ('cpu', 'gpu'));
-- The GPU adapter a worker opened and named at registration; NULL: it runs CPU jobs only. Only
-- workers with one claim jobs of `gpu` batches.
ALTER TABLE workers ADD COLUMN gpu TEXT;
