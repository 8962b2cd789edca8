"""The service's durable record: scenes, jobs and finished frames in SQLite.

One connection, shared by the event loop and the render thread under a lock (every statement
is short: a row read or written). The database holds records only; scene files, snapshots and
rendered frames live under the data directory (see :mod:`api.scenes` and :mod:`api.service`),
written atomically before the row that points at them.

Schema (version 1)::

    scenes(id, name, source, entry, created, version, triangles)
    jobs(id, seq, scene_id, status, request JSON, created, started, finished,
         frames_total, frames_done, scene_version, width, height, error, resumed)
    frames(job_id, frame, position, spp, seconds, error_estimate, path, created)

Job ``status`` is one of ``queued``, ``running``, ``done``, ``failed``, ``cancelled``.
"""

import json
import sqlite3
import threading
import time
from pathlib import Path
from typing import Any

SCHEMA_VERSION = 1
TERMINAL = ("done", "failed", "cancelled")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS scenes (
    id TEXT PRIMARY KEY,
    name TEXT NOT NULL,
    source TEXT NOT NULL,
    entry TEXT,
    created REAL NOT NULL,
    version INTEGER NOT NULL DEFAULT 0,
    triangles INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    seq INTEGER NOT NULL,
    scene_id TEXT NOT NULL,
    status TEXT NOT NULL,
    request TEXT NOT NULL,
    created REAL NOT NULL,
    started REAL,
    finished REAL,
    frames_total INTEGER NOT NULL,
    frames_done INTEGER NOT NULL DEFAULT 0,
    scene_version INTEGER NOT NULL,
    width INTEGER NOT NULL,
    height INTEGER NOT NULL,
    error TEXT,
    resumed INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX IF NOT EXISTS jobs_status ON jobs (status, seq);
CREATE TABLE IF NOT EXISTS frames (
    job_id TEXT NOT NULL,
    frame INTEGER NOT NULL,
    position INTEGER NOT NULL,
    spp INTEGER NOT NULL,
    seconds REAL NOT NULL,
    error_estimate REAL,
    path TEXT NOT NULL,
    created REAL NOT NULL,
    PRIMARY KEY (job_id, frame)
);
"""


class QueueFull(Exception):
    """No room for another job: ``active`` jobs are queued or running."""

    def __init__(self, active: int) -> None:
        super().__init__(f"{active} jobs are queued or running")
        self.active = active


class Store:
    """SQLite access for the service; every method is thread-safe."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._lock = threading.Lock()
        self._db = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None)
        self._db.row_factory = sqlite3.Row
        with self._lock:
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)
            row = self._db.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
            if row is None:
                self._db.execute(
                    "INSERT INTO meta (key, value) VALUES ('schema', ?)", (str(SCHEMA_VERSION),)
                )
            elif int(row["value"]) != SCHEMA_VERSION:
                raise RuntimeError(
                    f"{path}: database schema {row['value']}, this version reads {SCHEMA_VERSION}"
                )

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def _all(self, sql: str, args: tuple = ()) -> list[dict]:
        with self._lock:
            return [dict(r) for r in self._db.execute(sql, args).fetchall()]

    def _one(self, sql: str, args: tuple = ()) -> dict | None:
        with self._lock:
            row = self._db.execute(sql, args).fetchone()
        return None if row is None else dict(row)

    def _run(self, sql: str, args: tuple = ()) -> int:
        with self._lock:
            return self._db.execute(sql, args).rowcount

    # Scenes ------------------------------------------------------------------------------------

    def add_scene(self, scene_id: str, name: str, source: str, entry: str | None, triangles: int):
        self._run(
            "INSERT INTO scenes (id, name, source, entry, created, version, triangles) "
            "VALUES (?, ?, ?, ?, ?, 0, ?)",
            (scene_id, name, source, entry, time.time(), triangles),
        )

    def scene(self, scene_id: str) -> dict | None:
        return self._one("SELECT * FROM scenes WHERE id = ?", (scene_id,))

    def scenes(self) -> list[dict]:
        return self._all("SELECT * FROM scenes ORDER BY created, id")

    def set_scene_version(self, scene_id: str, version: int, triangles: int) -> None:
        self._run(
            "UPDATE scenes SET version = ?, triangles = ? WHERE id = ?",
            (version, triangles, scene_id),
        )

    def delete_scene(self, scene_id: str) -> bool:
        return self._run("DELETE FROM scenes WHERE id = ?", (scene_id,)) > 0

    # Jobs --------------------------------------------------------------------------------------

    def add_job(
        self,
        job_id: str,
        scene_id: str,
        request: dict,
        frames_total: int,
        scene_version: int,
        width: int,
        height: int,
        max_active: int | None = None,
    ) -> dict:
        """Record a queued job; with ``max_active``, only while fewer jobs than that are queued
        or running (counted and added as one step, so concurrent submissions cannot pass the
        limit together), else :class:`QueueFull`."""
        with self._lock:
            if max_active is not None:
                active = self._db.execute(
                    "SELECT COUNT(*) FROM jobs WHERE status IN ('queued', 'running')"
                ).fetchone()[0]
                if active >= max_active:
                    raise QueueFull(active)
            seq = self._db.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM jobs").fetchone()[0]
            self._db.execute(
                "INSERT INTO jobs (id, seq, scene_id, status, request, created, frames_total, "
                "scene_version, width, height) VALUES (?, ?, ?, 'queued', ?, ?, ?, ?, ?, ?)",
                (
                    job_id, seq, scene_id, json.dumps(request), time.time(), frames_total,
                    scene_version, width, height,
                ),
            )  # fmt: skip
        return self.job(job_id)

    def job(self, job_id: str) -> dict | None:
        row = self._one("SELECT * FROM jobs WHERE id = ?", (job_id,))
        if row is not None:
            row["request"] = json.loads(row["request"])
        return row

    def jobs(self, status: str | None = None, limit: int = 100, offset: int = 0) -> list[dict]:
        if status is None:
            rows = self._all(
                "SELECT * FROM jobs ORDER BY seq DESC LIMIT ? OFFSET ?", (limit, offset)
            )
        else:
            rows = self._all(
                "SELECT * FROM jobs WHERE status = ? ORDER BY seq DESC LIMIT ? OFFSET ?",
                (status, limit, offset),
            )
        for row in rows:
            row["request"] = json.loads(row["request"])
        return rows

    def unfinished_jobs(self) -> list[dict]:
        rows = self._all("SELECT * FROM jobs WHERE status IN ('queued', 'running') ORDER BY seq")
        for row in rows:
            row["request"] = json.loads(row["request"])
        return rows

    def update_job(self, job_id: str, **fields: Any) -> None:
        if not fields:
            return
        names = ", ".join(f"{k} = ?" for k in fields)
        self._run(f"UPDATE jobs SET {names} WHERE id = ?", (*fields.values(), job_id))

    def start_job(self, job_id: str) -> bool:
        """Mark a queued (or resuming) job running; False if it was finished meanwhile (e.g.
        cancelled between the render thread's read of it and this update)."""
        return (
            self._run(
                "UPDATE jobs SET status = 'running', started = COALESCE(started, ?) "
                "WHERE id = ? AND status IN ('queued', 'running')",
                (time.time(), job_id),
            )
            > 0
        )

    def finish_job(self, job_id: str, status: str, error: str | None = None) -> bool:
        """Move an unfinished job to a terminal status; False if it already was terminal."""
        return (
            self._run(
                "UPDATE jobs SET status = ?, error = ?, finished = ? "
                "WHERE id = ? AND status IN ('queued', 'running')",
                (status, error, time.time(), job_id),
            )
            > 0
        )

    # Frames ------------------------------------------------------------------------------------

    def add_frame(
        self,
        job_id: str,
        frame: int,
        position: int,
        spp: int,
        seconds: float,
        path: str,
        error_estimate: float | None = None,
    ) -> None:
        with self._lock:
            self._db.execute("BEGIN")
            try:
                self._db.execute(
                    "INSERT OR REPLACE INTO frames (job_id, frame, position, spp, seconds, "
                    "error_estimate, path, created) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                    (job_id, frame, position, spp, seconds, error_estimate, path, time.time()),
                )
                self._db.execute(
                    "UPDATE jobs SET frames_done = (SELECT COUNT(*) FROM frames WHERE job_id = ?) "
                    "WHERE id = ?",
                    (job_id, job_id),
                )
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise

    def frames(self, job_id: str) -> list[dict]:
        return self._all("SELECT * FROM frames WHERE job_id = ? ORDER BY position", (job_id,))

    def frame(self, job_id: str, frame: int) -> dict | None:
        return self._one("SELECT * FROM frames WHERE job_id = ? AND frame = ?", (job_id, frame))
