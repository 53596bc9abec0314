"""The SQLite index of the simulation store (``index.sqlite``): its schema, the statement that writes a row, and
opening it (journal, integrity check, and the upgrade of an index written before a column existed).

Table ``sims`` holds one row per simulation: its key, request (canonical JSON), status, error and wall time, and
the columns that :meth:`mpm.store.Store.materials` searches: the request's ``setting`` (its key without the
material) and its material.  Table ``losses`` holds video losses per (request key, experiment id).
"""
from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Callable

SCHEMA = """
CREATE TABLE IF NOT EXISTS sims (
    key TEXT PRIMARY KEY,
    request TEXT NOT NULL,
    status TEXT NOT NULL,
    error TEXT,
    wall_seconds REAL,
    created REAL NOT NULL,
    setting TEXT,
    eta REAL,
    n REAL,
    sigma_y REAL
);
CREATE TABLE IF NOT EXISTS losses (
    key TEXT NOT NULL,
    experiment TEXT NOT NULL,
    loss REAL,
    PRIMARY KEY (key, experiment)
);
"""
INSERT_SIM = ("INSERT OR REPLACE INTO sims (key, request, status, error, wall_seconds, created, setting, eta, n, "
              "sigma_y) VALUES (?,?,?,?,?,?,?,?,?,?)")
_SETTING_COLUMNS = ("setting TEXT", "eta REAL", "n REAL", "sigma_y REAL")


def open_index(path: Path, setting_of: Callable[[str], tuple]) -> sqlite3.Connection:
    """Open (or create) the index at ``path``; sqlite3.DatabaseError when it is damaged.  ``setting_of(request
    JSON)`` gives (setting, eta, n, sigma_y) for the rows of an index written before those columns."""
    db = sqlite3.connect(path, timeout=60.0, isolation_level=None)
    try:
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=NORMAL")
        ok = db.execute("PRAGMA quick_check").fetchone()
        if ok is None or ok[0] != "ok":
            raise sqlite3.DatabaseError(f"integrity check failed: {ok[0] if ok else 'no answer'}")
        db.executescript(SCHEMA)
        if not _has_setting(db):
            with db:
                db.execute("BEGIN IMMEDIATE")
                if not _has_setting(db):  # else another process upgraded it meanwhile
                    for column in _SETTING_COLUMNS:
                        db.execute(f"ALTER TABLE sims ADD COLUMN {column}")
                    rows = db.execute("SELECT key, request FROM sims").fetchall()
                    db.executemany("UPDATE sims SET setting=?, eta=?, n=?, sigma_y=? WHERE key=?",
                                   [(*setting_of(request), key) for key, request in rows])
        db.execute("CREATE INDEX IF NOT EXISTS sims_setting ON sims (setting)")
    except BaseException:
        db.close()
        raise
    return db


def _has_setting(db: sqlite3.Connection) -> bool:
    return "setting" in {row[1] for row in db.execute("PRAGMA table_info(sims)")}
