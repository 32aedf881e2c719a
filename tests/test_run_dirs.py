"""Run directories (lwm_models/run_dirs.py): where a run keeps its ledger and the world-model
server's manual, and what a new run refuses to continue silently."""

from __future__ import annotations

import json

from lwm_models import run_dirs


def test_a_run_made_before_the_rename_keeps_its_manual(tmp_path):
    """Runs made while the server was called the simulator saved its manual as
    simulator_state.json: resuming one must find that manual, and a new run uses the new name."""
    assert run_dirs.state_file(tmp_path) == tmp_path / run_dirs.STATE_FILE
    old = tmp_path / run_dirs.OLD_STATE_FILE
    old.write_text(json.dumps({"manual_version": 3}))
    assert run_dirs.state_file(tmp_path) == old
    assert run_dirs.earlier_run_files(tmp_path / run_dirs.LEDGER_FILE, run_dirs.state_file(tmp_path)) == [old]
    (tmp_path / run_dirs.STATE_FILE).write_text("{}")  # once saved under the new name, that one counts
    assert run_dirs.state_file(tmp_path) == tmp_path / run_dirs.STATE_FILE
