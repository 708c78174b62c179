-- The job store on PostgreSQL (server/src/jobs/postgres.rs): the SQLite store's two tables, with
-- a lease per running scene so that several replicas can share the queue.
CREATE TABLE jobs (
    seq BIGSERIAL PRIMARY KEY,
    id TEXT NOT NULL UNIQUE,
    -- The job's label vocabulary, a JSON array of words; NULL: the server's.
    vocabulary JSONB,
    refine_steps INTEGER,
    cancelled BOOLEAN NOT NULL DEFAULT FALSE,
    created_at TIMESTAMPTZ NOT NULL DEFAULT now()
);

CREATE TABLE job_scenes (
    job_id TEXT NOT NULL REFERENCES jobs (id),
    idx INTEGER NOT NULL,
    name TEXT NOT NULL,
    input TEXT NOT NULL,
    state TEXT NOT NULL CHECK (state IN ('queued', 'running', 'done', 'failed', 'cancelled')),
    scene_id TEXT,
    error TEXT,
    metrics JSONB,
    attempts INTEGER NOT NULL DEFAULT 0,
    -- The replica running the scene and until when its claim holds; past it, another may run it.
    lease_owner TEXT,
    lease_until TIMESTAMPTZ,
    PRIMARY KEY (job_id, idx)
);

CREATE INDEX job_scenes_open ON job_scenes (state) WHERE state IN ('queued', 'running');
