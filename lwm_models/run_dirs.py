"""Where a run of the system keeps what it writes: one directory per run.

A run (one `./run_nodes.sh`) writes its review ledger, the world-model server's current manual, the
planner's policy snapshots and every node's log into a directory of its own, `logs/runs/<time>`,
and `logs/latest` points at the newest. So a second run starts clean: it does not resume the
reviews, the manual or the learnt policy of the first. `--resume` continues an earlier run's
directory instead. What is kept across runs on purpose: the reviewers' keys
(`logs/reviewer_keys.json`), which are the reviewers' identities, not a review's state.
"""

from __future__ import annotations

import os
import sqlite3
import time
from pathlib import Path
from urllib.parse import quote

LOGS = Path(os.environ.get("LWM_LOGS", "logs"))
LATEST = "latest"
LEDGER_FILE = "ledger.sqlite"
STATE_FILE = "world_model_state.json"  # the world-model server's manual and its version
OLD_STATE_FILE = "simulator_state.json"  # its name in runs made before the server was named so
KEYS_FILE = "reviewer_keys.json"
EPISODE_FILE = "episode.json"  # the episode the environment plays, which a restart or --resume returns to
DEFAULT_LEDGER = Path(os.environ.get("LWM_LEDGER", LOGS / LATEST / LEDGER_FILE))


def state_file(run_dir: Path) -> Path:
    """The world-model server's saved manual in run_dir; a run made before the rename keeps its
    file under the old name, and resuming it must find it there."""
    old = run_dir / OLD_STATE_FILE
    return old if old.is_file() and not (run_dir / STATE_FILE).exists() else run_dir / STATE_FILE


def new_run_dir(root: Path = LOGS) -> Path:
    """A fresh directory logs/runs/<UTC time>[-n], which logs/latest then points at."""
    runs = root / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    for n in range(1000):
        path = runs / (stamp if n == 0 else f"{stamp}-{n}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        point_latest(path, root)
        return path
    raise RuntimeError(f"cannot make a new run directory under {runs}")


def point_latest(run_dir: Path, root: Path = LOGS) -> None:
    """Make root/latest a (relative) link to run_dir, replacing the old link atomically."""
    link = root / LATEST
    tmp = root / f".{LATEST}.{os.getpid()}"
    tmp.unlink(missing_ok=True)
    tmp.symlink_to(os.path.relpath(run_dir.resolve(), root.resolve()))
    os.replace(tmp, link)


def latest_run_dir(root: Path = LOGS) -> Path | None:
    link = root / LATEST
    return link.resolve() if link.is_dir() else None


def earlier_run_files(ledger: Path, state: Path) -> list[Path]:
    """What an earlier run left that a new one would silently continue: a ledger with records,
    and the world-model server's saved manual."""
    found = []
    if ledger.is_file():
        try:
            db = sqlite3.connect(f"file:{quote(str(ledger.resolve()))}?mode=ro", uri=True)
            try:
                records = db.execute("SELECT COUNT(*) FROM records").fetchone()[0]
            finally:
                db.close()
        except sqlite3.Error:
            records = 1  # not a ledger we can read: never write over it unasked
        if records:
            found.append(ledger)
    if state.is_file() and state.stat().st_size > 0:
        found.append(state)
    return found


__all__ = ["DEFAULT_LEDGER", "LOGS", "earlier_run_files", "latest_run_dir", "new_run_dir", "point_latest", "state_file"]
