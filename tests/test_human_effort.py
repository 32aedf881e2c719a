"""benchmarks/human_effort.py's summary: each column over the same games, with Table 3's records of
every state labelled and of the agent with no controller beside the label budgets."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _benchmark():
    spec = importlib.util.spec_from_file_location("human_effort", ROOT / "benchmarks" / "human_effort.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _effort(model: str, game: int, budget: int, ret: float) -> dict:
    return {"model": model, "game": game, "budget": budget, "return": ret, "labels_asked": budget // 2,
            "roles_right": True, "wait_seconds": 1.0}  # fmt: skip


def _table3(setting: str, model: str, game: int, ret: float) -> str:
    return json.dumps({"setting": setting, "model": model, "split": "newall-test", "game": game, "return": ret})


def test_the_summary_puts_every_state_and_no_controller_beside_the_budgets_on_the_same_games(tmp_path):
    he = _benchmark()
    he.EVERY_STATE = {"emma": tmp_path / "every.jsonl"}
    he.NO_CONTROLLER = tmp_path / "none.jsonl"
    games = (0, 29, 59)
    he.EVERY_STATE["emma"].write_text("\n".join(_table3("online_il", "emma", g, 1.5) for g in games) + "\n")
    learnt = [_table3("imagined_returns", "emma", g, r) for g, r in zip(games, (1.5, -1.0, 0.0), strict=True)]
    learnt += [_table3("imagined_returns", "emma", 88, 1.5), _table3("imagined_returns", "observational", 0, 1.5)]
    he.NO_CONTROLLER.write_text("\n".join(learnt) + "\n")
    records = [_effort("emma", g, b, 0.5) for g in games for b in (0, 10)]
    summary = he.summarize(records, "newall-test")["emma"]
    assert set(summary) == {"0", "10", "all", "none"}
    assert summary["all"]["mean"] == 1.5 and summary["all"]["games"] == 3
    # Only the games the budgets were measured on: game 88's record is left out.
    assert summary["none"]["games"] == 3 and abs(summary["none"]["mean"] - 0.5 / 3) < 1e-4
    assert summary["none"]["low"] < summary["none"]["mean"] < summary["none"]["high"]
    # A learner measured on fewer of the games is no column: the cells would not compare.
    he.NO_CONTROLLER.write_text("\n".join(learnt[:2]) + "\n")
    assert "none" not in he.summarize(records, "newall-test")["emma"]
