"""The service's state: one SQLite database under `--data` (no server to install).

Bodies and fits are rows; a fit's row is also its job: `queued` until a worker claims it,
`running` while it works, then `predicted` (a learned answer, refinement under way),
`refined` or `simulated` (done), or `failed` with a reason. Every change is one short
transaction, so the server and its worker processes can write it side by side (WAL).
A job found `running` when the server starts was cut off by a stop or a crash: it is
queued again, or failed with that reason after `MAX_ATTEMPTS`.
"""

from __future__ import annotations

import json
import secrets
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path

MAX_ATTEMPTS = 2
DONE = ("refined", "simulated", "failed")

SCHEMA = """
CREATE TABLE IF NOT EXISTS bodies (id TEXT PRIMARY KEY, created REAL, request TEXT, result TEXT);
CREATE TABLE IF NOT EXISTS fits (id TEXT PRIMARY KEY, body_id TEXT, request TEXT, status TEXT, progress REAL,
                                 result TEXT, reason TEXT, attempts INTEGER, created REAL, updated REAL,
                                 started REAL);
CREATE INDEX IF NOT EXISTS fits_status ON fits (status, created);
CREATE TABLE IF NOT EXISTS idempotency (key TEXT PRIMARY KEY, route TEXT, response TEXT, created REAL);
"""


def new_id(prefix: str) -> str:
    return f"{prefix}_{secrets.token_hex(8)}"


@dataclass
class FitRow:
    id: str
    body_id: str
    request: dict
    status: str
    progress: float
    result: dict | None
    reason: str | None
    attempts: int
    created: float
    updated: float
    started: float | None


class Store:
    """The database at `path` (created on first use)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self._db() as db:
            db.execute("PRAGMA journal_mode=WAL")
            db.executescript(SCHEMA)

    def _db(self) -> sqlite3.Connection:
        db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
        db.row_factory = sqlite3.Row
        return db

    def _run(self, sql: str, args: tuple = ()) -> list[sqlite3.Row]:
        db = self._db()
        try:
            return db.execute(sql, args).fetchall()
        finally:
            db.close()

    # -- bodies
    def add_body(self, request: dict, result: dict) -> str:
        body_id = new_id("body")
        self._run("INSERT INTO bodies VALUES (?, ?, ?, ?)", (body_id, time.time(), json.dumps(request), json.dumps(result)))
        return body_id

    def body(self, body_id: str) -> tuple[dict, dict] | None:
        rows = self._run("SELECT request, result FROM bodies WHERE id = ?", (body_id,))
        return (json.loads(rows[0]["request"]), json.loads(rows[0]["result"])) if rows else None

    # -- fits
    def add_fit(self, body_id: str, request: dict) -> str:
        fit_id = new_id("fit")
        now = time.time()
        self._run("INSERT INTO fits VALUES (?, ?, ?, 'queued', 0.0, NULL, NULL, 0, ?, ?, NULL)",
                  (fit_id, body_id, json.dumps(request), now, now))
        return fit_id

    def fit(self, fit_id: str) -> FitRow | None:
        rows = self._run("SELECT * FROM fits WHERE id = ?", (fit_id,))
        if not rows:
            return None
        r = rows[0]
        return FitRow(r["id"], r["body_id"], json.loads(r["request"]), r["status"], r["progress"],
                      json.loads(r["result"]) if r["result"] else None, r["reason"], r["attempts"], r["created"],
                      r["updated"], r["started"])

    def claim_next(self) -> str | None:
        """The oldest queued fit, marked running (None when none waits)."""
        db = self._db()
        try:
            db.execute("BEGIN IMMEDIATE")
            row = db.execute("SELECT id FROM fits WHERE status = 'queued' ORDER BY created LIMIT 1").fetchone()
            if row is None:
                db.execute("COMMIT")
                return None
            now = time.time()
            db.execute("UPDATE fits SET status = 'running', attempts = attempts + 1, started = ?, updated = ? "
                       "WHERE id = ?", (now, now, row["id"]))
            db.execute("COMMIT")
            return row["id"]
        finally:
            db.close()

    def update(self, fit_id: str, status: str, progress: float, result: dict | None = None, reason: str | None = None) -> None:
        """A fit's new state. A fit already done is left as it is."""
        self._run("UPDATE fits SET status = ?, progress = ?, result = COALESCE(?, result), reason = ?, updated = ? "
                  f"WHERE id = ? AND status NOT IN {DONE}",
                  (status, progress, json.dumps(result) if result is not None else None, reason, time.time(), fit_id))

    def requeue_or_fail(self, fit_id: str, reason: str) -> str:
        """A job cut off (its worker died, the server stopped): queued again, or failed
        with `reason` once it has been tried `MAX_ATTEMPTS` times. Returns the new status."""
        row = self.fit(fit_id)
        if row is None or row.status in DONE:
            return row.status if row else "missing"
        if row.attempts >= MAX_ATTEMPTS:
            self.update(fit_id, "failed", row.progress, reason=f"{reason} (tried {row.attempts} times)")
            return "failed"
        self._run("UPDATE fits SET status = 'queued', updated = ? WHERE id = ?", (time.time(), fit_id))
        return "queued"

    def recover(self) -> dict[str, int]:
        """At start: every fit left running or predicted (refinement cut off) goes back to
        the queue, or fails after `MAX_ATTEMPTS`."""
        counts = {"queued": 0, "failed": 0}
        for r in self._run("SELECT id FROM fits WHERE status IN ('running', 'predicted')"):
            status = self.requeue_or_fail(r["id"], "the server stopped while it ran")
            counts[status] = counts.get(status, 0) + 1
        return counts

    def counts(self) -> dict[str, int]:
        return {r["status"]: r["n"] for r in self._run("SELECT status, COUNT(*) AS n FROM fits GROUP BY status")}

    def waiting(self) -> int:
        return int(self._run("SELECT COUNT(*) AS n FROM fits WHERE status IN ('queued', 'running')")[0]["n"])

    def running_since(self) -> list[tuple[str, float]]:
        return [(r["id"], r["started"]) for r in self._run("SELECT id, started FROM fits WHERE status = 'running'")]

    def prune(self, keep_s: float) -> list[str]:
        """Forget fits finished more than `keep_s` ago; their ids (their files go too)."""
        cutoff = time.time() - keep_s
        rows = self._run(f"SELECT id FROM fits WHERE status IN {DONE} AND updated < ?", (cutoff,))
        self._run(f"DELETE FROM fits WHERE status IN {DONE} AND updated < ?", (cutoff,))
        self._run("DELETE FROM idempotency WHERE created < ?", (cutoff,))
        return [r["id"] for r in rows]

    # -- idempotent POSTs
    def remembered(self, key: str, route: str) -> dict | None:
        rows = self._run("SELECT route, response FROM idempotency WHERE key = ?", (key,))
        if not rows:
            return None
        if rows[0]["route"] != route:
            return {"conflict": rows[0]["route"]}
        return json.loads(rows[0]["response"])

    def remember(self, key: str, route: str, response: dict) -> None:
        self._run("INSERT OR IGNORE INTO idempotency VALUES (?, ?, ?, ?)", (key, route, json.dumps(response), time.time()))
