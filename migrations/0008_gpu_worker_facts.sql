-- What a GPU worker reports of its GPU at registration (issue 49): the device's memory in bytes
-- (NULL: not known) and how many runs it shares the GPU among at once (its GPU slots; NULL for
-- a worker without a GPU, or one from before this migration).
ALTER TABLE workers ADD COLUMN gpu_memory_bytes INTEGER;
ALTER TABLE workers ADD COLUMN gpu_slots INTEGER;
