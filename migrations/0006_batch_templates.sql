-- Write amplification: the experiment spec is stored once per batch instead of once per run.
-- `template` is the complete experiment spec (preset + overrides) before any factor value is
-- written in; a run's spec is the template with the run's `natural` values written at the
-- factor paths (the `path`s of the request's factors, in factor order). Runs of such batches
-- store '' in `spec`; batches from before this migration keep a NULL template and their runs'
-- full specs.
ALTER TABLE batches ADD COLUMN template TEXT;
