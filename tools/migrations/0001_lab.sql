-- The lab's archive (docs/LESSONS.md, "The lab's archive"): one schema for SQLite and
-- PostgreSQL, so only types and statements both take (TEXT, BIGINT, DOUBLE PRECISION; a
-- flag as 0/1). Every row is rebuilt from the journals by `scalpel archive rebuild`.

CREATE TABLE trainees (
    name TEXT PRIMARY KEY
);

-- A lesson as a station ran it: its id is the SHA-256 of its text, so an edited lesson
-- is another lesson and old scores keep the lesson they were scored on.
CREATE TABLE lessons (
    id TEXT PRIMARY KEY,
    name TEXT NOT NULL,
    description TEXT NOT NULL,
    scene TEXT NOT NULL,
    min_score DOUBLE PRECISION NOT NULL,
    text TEXT NOT NULL
);

-- A station's session: its id is the SHA-256 of its journal.
CREATE TABLE sessions (
    id TEXT PRIMARY KEY,
    journal TEXT NOT NULL,
    station TEXT NOT NULL,
    scene TEXT NOT NULL,
    trainee TEXT REFERENCES trainees (name),
    lesson TEXT REFERENCES lessons (id),
    started_unix_s BIGINT,
    ticks BIGINT NOT NULL,
    archived_unix_s BIGINT NOT NULL
);

CREATE INDEX sessions_by_trainee ON sessions (trainee, started_unix_s);

-- A session's score on its lesson (sessions without a lesson have none).
CREATE TABLE scores (
    session TEXT PRIMARY KEY REFERENCES sessions (id),
    score DOUBLE PRECISION NOT NULL,
    passed BIGINT NOT NULL,
    time_s DOUBLE PRECISION NOT NULL,
    rms_deviation_mm DOUBLE PRECISION NOT NULL,
    rms_depth_error_mm DOUBLE PRECISION NOT NULL,
    completed_percent DOUBLE PRECISION NOT NULL,
    economy DOUBLE PRECISION NOT NULL,
    peak_force_n DOUBLE PRECISION NOT NULL,
    critical_events BIGINT NOT NULL,
    no_go_cuts BIGINT NOT NULL,
    off_band_area_mm2 DOUBLE PRECISION NOT NULL,
    reasons TEXT NOT NULL,
    report TEXT NOT NULL
);
