"""The service's state: one SQLite database under `--data` (no server to install).

Bodies and fits are rows; a fit's row is also its job, done in phases (`PHASES`): a
garment with a learned model is first answered (`answer`: every size predicted, in a
fraction of a second), then refined (`refine`: the sizes that decide, seconds); any other
garment is simulated (`simulate`, minutes). A phase is claimed by one worker at a time.
The status a shopper sees: `queued` until the first phase starts, `running` while it works,
then `predicted` (a learned answer, refinement waiting or under way), `refined` or
`simulated` (done), or `failed` with a reason. Every change is one short transaction, so
the server and its worker processes can write it side by side (WAL). A phase found claimed
when the server starts was cut off by a stop or a crash: it is claimable again, or the fit
fails with that reason after `MAX_ATTEMPTS` tries of that phase.
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
PHASES = ("answer", "refine", "simulate")

SCHEMA = """
CREATE TABLE IF NOT EXISTS bodies (id TEXT PRIMARY KEY, created REAL, request TEXT, result TEXT);
CREATE TABLE IF NOT EXISTS fits (id TEXT PRIMARY KEY, body_id TEXT, request TEXT, status TEXT, progress REAL,
                                 result TEXT, reason TEXT, attempts INTEGER, created REAL, updated REAL,
                                 started REAL, phase TEXT DEFAULT 'answer', claimed INTEGER DEFAULT 0);
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
    phase: str
    claimed: bool


class Store:
    """The database at `path` (created on first use)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self._db() as db:
            db.execute("PRAGMA journal_mode=WAL")
            db.executescript(SCHEMA)
            columns = {r["name"] for r in db.execute("PRAGMA table_info(fits)")}
            for name, decl in (("phase", "TEXT DEFAULT 'answer'"), ("claimed", "INTEGER DEFAULT 0")):
                if name not in columns:  # a database of the first version
                    db.execute(f"ALTER TABLE fits ADD COLUMN {name} {decl}")

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
    def add_body(self, request: dict, result: dict, body_id: str | None = None) -> str:
        body_id = body_id or new_id("body")
        self._run("INSERT INTO bodies VALUES (?, ?, ?, ?)", (body_id, time.time(), json.dumps(request), json.dumps(result)))
        return body_id

    def body(self, body_id: str) -> tuple[dict, dict] | None:
        rows = self._run("SELECT request, result FROM bodies WHERE id = ?", (body_id,))
        return (json.loads(rows[0]["request"]), json.loads(rows[0]["result"])) if rows else None

    # -- fits
    def add_fit(self, body_id: str, request: dict, phase: str = "answer") -> str:
        """A new fit, waiting for its first phase (`answer` or `simulate`)."""
        if phase not in ("answer", "simulate"):
            raise ValueError(f"a fit starts with the answer or simulate phase, not {phase!r}")
        fit_id = new_id("fit")
        now = time.time()
        self._run("INSERT INTO fits VALUES (?, ?, ?, 'queued', 0.0, NULL, NULL, 0, ?, ?, NULL, ?, 0)",
                  (fit_id, body_id, json.dumps(request), now, now, phase))
        return fit_id

    def fit(self, fit_id: str) -> FitRow | None:
        rows = self._run("SELECT * FROM fits WHERE id = ?", (fit_id,))
        if not rows:
            return None
        r = rows[0]
        return FitRow(r["id"], r["body_id"], json.loads(r["request"]), r["status"], r["progress"],
                      json.loads(r["result"]) if r["result"] else None, r["reason"], r["attempts"], r["created"],
                      r["updated"], r["started"], r["phase"], bool(r["claimed"]))

    def claim_next(self, phases: tuple[str, ...] = PHASES) -> tuple[str, str] | None:
        """(fit id, phase) of the oldest unclaimed fit waiting for one of `phases`, now
        claimed (None when none waits). A fit's first phase turns it `running`."""
        marks = ", ".join("?" * len(phases))
        db = self._db()
        try:
            db.execute("BEGIN IMMEDIATE")
            row = db.execute(f"SELECT id, phase FROM fits WHERE claimed = 0 AND phase IN ({marks}) AND status NOT IN "
                             f"{DONE} ORDER BY created LIMIT 1", phases).fetchone()
            if row is None:
                db.execute("COMMIT")
                return None
            now = time.time()
            db.execute("UPDATE fits SET claimed = 1, attempts = attempts + 1, started = ?, updated = ?, "
                       "status = CASE status WHEN 'queued' THEN 'running' ELSE status END WHERE id = ?",
                       (now, now, row["id"]))
            db.execute("COMMIT")
            return row["id"], row["phase"]
        finally:
            db.close()

    def update(self, fit_id: str, status: str, progress: float, result: dict | None = None, reason: str | None = None) -> None:
        """A fit's new state. A fit already done is left as it is."""
        self._run("UPDATE fits SET status = ?, progress = ?, result = COALESCE(?, result), reason = ?, updated = ? "
                  f"WHERE id = ? AND status NOT IN {DONE}",
                  (status, progress, json.dumps(result) if result is not None else None, reason, time.time(), fit_id))

    def next_phase(self, fit_id: str, phase: str) -> None:
        """The fit's current phase is done; it waits for `phase`, unclaimed, with fresh tries."""
        self._run(f"UPDATE fits SET phase = ?, claimed = 0, attempts = 0, updated = ? WHERE id = ? AND status NOT IN "
                  f"{DONE}", (phase, time.time(), fit_id))

    def requeue_or_fail(self, fit_id: str, reason: str, phase: str | None = None, charge: bool = True) -> str:
        """A phase cut off (its worker died, the server stopped): claimable again, or the
        fit failed with `reason` once the phase has been tried `MAX_ATTEMPTS` times (what
        an earlier phase answered is kept). Only a fit still claimed in `phase` (any phase
        when None) is touched: a phase that finished, or was claimed again since, is left
        alone. `charge=False` when the phase was cut off for another job's trouble (a pool
        replaced for a neighbour, the server stopping): the try is given back. Returns the
        fit's status."""
        db = self._db()
        try:
            db.execute("BEGIN IMMEDIATE")
            row = db.execute("SELECT status, progress, attempts, phase, claimed FROM fits WHERE id = ?", (fit_id,)).fetchone()
            if row is None:
                db.execute("COMMIT")
                return "missing"
            if row["status"] in DONE or not row["claimed"] or (phase is not None and row["phase"] != phase):
                db.execute("COMMIT")
                return row["status"]
            attempts = row["attempts"] if charge else max(0, row["attempts"] - 1)
            now = time.time()
            if attempts >= MAX_ATTEMPTS:
                db.execute("UPDATE fits SET status = 'failed', reason = ?, claimed = 0, updated = ? WHERE id = ?",
                           (f"{reason} (tried {attempts} times)", now, fit_id))
                status = "failed"
            else:
                status = "queued" if row["status"] == "running" else row["status"]
                db.execute("UPDATE fits SET status = ?, claimed = 0, attempts = ?, updated = ? WHERE id = ?",
                           (status, attempts, now, fit_id))
            db.execute("COMMIT")
            return status
        finally:
            db.close()

    def claimed(self) -> list[tuple[str, str]]:
        """(fit id, phase) of every fit claimed by a worker and not done."""
        return [(r["id"], r["phase"]) for r in self._run(f"SELECT id, phase FROM fits WHERE claimed = 1 AND status NOT IN {DONE}")]

    def recover(self) -> dict[str, int]:
        """At start: every phase left claimed (cut off) is claimable again, or its fit
        fails after `MAX_ATTEMPTS`."""
        counts: dict[str, int] = {}
        for fit_id, phase in self.claimed():
            status = self.requeue_or_fail(fit_id, "the server stopped while it ran", phase)
            counts[status] = counts.get(status, 0) + 1
        return counts

    def counts(self) -> dict[str, int]:
        return {r["status"]: r["n"] for r in self._run("SELECT status, COUNT(*) AS n FROM fits GROUP BY status")}

    def waiting(self) -> int:
        """Fits not done yet (queued, running, or predicted and waiting for refinement)."""
        return int(self._run(f"SELECT COUNT(*) AS n FROM fits WHERE status NOT IN {DONE}")[0]["n"])

    def prune(self, keep_s: float) -> tuple[list[str], list[str]]:
        """Forget fits finished more than `keep_s` ago, and bodies posted before that which
        no fit still uses; (their fit ids, their body ids): their files go too."""
        cutoff = time.time() - keep_s
        fits = [r["id"] for r in self._run(f"SELECT id FROM fits WHERE status IN {DONE} AND updated < ?", (cutoff,))]
        self._run(f"DELETE FROM fits WHERE status IN {DONE} AND updated < ?", (cutoff,))
        unused = "created < ? AND id NOT IN (SELECT body_id FROM fits)"
        bodies = [r["id"] for r in self._run(f"SELECT id FROM bodies WHERE {unused}", (cutoff,))]
        self._run(f"DELETE FROM bodies WHERE {unused}", (cutoff,))
        self._run("DELETE FROM idempotency WHERE created < ?", (cutoff,))
        return fits, bodies

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
