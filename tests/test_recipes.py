"""Named recipes (configs/*.json): each is what its shipped checkpoint was trained with, the command
line overrides it, and a recipe that cannot be used is one line and status 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from lwm_models.cli import main as cli_main
from lwm_models.cli import recipes
from lwm_models.world.shipped import POLICY, WORLD_MODELS

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
CHECKPOINTS = ROOT / "lwm_models" / "checkpoints"
# A chunk's length, its progress bar and where the run kept its state are how one session ran, not
# how the model was trained.
PER_CHUNK = {"max_minutes", "progress", "tensorboard", "out"}
# recipe -> shipped checkpoint (lwm_models/world/shipped.py); oracle-long is the stopped long run of
# OracleParse, not shipped
SHIPPED = {m.directory: m.directory for m in (*WORLD_MODELS, POLICY)}


def _parse(argv: list[str]):
    parser = cli_main.build_parser([])
    return parser.parse_args(recipes.expand(parser, argv))


def _recipe(name: str) -> dict:
    return json.loads((CONFIGS / f"{name}.json").read_text())


def test_every_shipped_checkpoint_has_its_recipe():
    assert {p.stem for p in CONFIGS.glob("*.json")} == set(SHIPPED) | {"oracle-long"}
    assert {p.name for p in CHECKPOINTS.iterdir() if (p / "config.json").is_file()} == set(SHIPPED.values())


@pytest.mark.parametrize("name", [m.directory for m in WORLD_MODELS])
def test_a_world_model_recipe_parses_to_what_its_checkpoint_was_trained_with(name, tmp_path):
    from lwm_models.world.reader_tuning import ReaderTuningArgs
    from lwm_models.world.train import TrainArgs

    config = json.loads((CHECKPOINTS / SHIPPED[name] / "config.json").read_text())
    command = _recipe(name)["command"]
    if command == "scripts/hedged_checkpoint.py":  # nothing trained: another checkpoint plus prototypes
        from lwm_models.world.hedged_reading import DOUBT, MAX_READINGS, PROTOTYPE_TEXTS, STAND_QUANTILE

        made = {k: v for k, v in config["hedged_reading"].items() if k != "stand_distance"}  # fitted, not given
        made = {"max_readings": MAX_READINGS, "keep_readings": 0, **made}  # what the loader takes where unsaid
        assert made == {
            "max_readings": MAX_READINGS,  # unless the recipe gives another
            "keep_readings": 0,  # unless the recipe prunes the readings after the first steps
            "prototype_texts": PROTOTYPE_TEXTS,
            "stand_quantile": STAND_QUANTILE,  # unless the recipe gives another (GPTHard: 0)
            "ground": False,  # unless the recipe grounds the words on the board
            "doubt": DOUBT,  # unless the recipe gives another (GPTHard: 0, not yet measured on held-out text)
            **_recipe(name)["options"],
            "rule": "mixture",  # the script's rule: every reading the words allow
        }
        return
    # A checkpoint records the arguments of the command that made it: `lwm train`'s or `lwm tune-reader`'s.
    fields, trained = {
        "lwm train": (TrainArgs, config.get("train_args")),
        "lwm tune-reader": (ReaderTuningArgs, config.get("reader_tuning")),
    }[command]
    assert trained is not None, f"{name}: the checkpoint does not record the arguments of {command}"
    # --data is given because data/human need not exist here; the recipe names the same directory
    args = _parse([command.split()[1], "--config", str(CONFIGS / f"{name}.json"), "--data", str(tmp_path)])
    assert _recipe(name)["options"]["data"] == trained["data"]
    assert args.data == str(tmp_path)
    parsed = {f: getattr(args, f) for f in fields.__dataclass_fields__}
    for key, value in trained.items():
        if key in PER_CHUNK or key == "data":
            continue
        if key not in parsed:
            raise AssertionError(f"{name}: the checkpoint records {key}, which {command} no longer has")
        assert parsed[key] == value, f"{name}: {key} is {parsed[key]!r}, the checkpoint was trained with {value!r}"
    if command == "lwm train" and "parts" not in trained:  # trained before batches in parts: one padded batch
        assert parsed["parts"] == 1


def test_the_policy_recipe_parses_to_what_the_shipped_policy_was_trained_with(tmp_path):
    trained = json.loads((CHECKPOINTS / "policy-bc" / "config.json").read_text())["trained"]
    args = _parse(["agent", "pretrain", "--config", str(CONFIGS / "policy-bc.json"), "--data", str(tmp_path)])
    assert trained["command"] == _recipe("policy-bc")["command"] == "lwm agent pretrain"
    assert _recipe("policy-bc")["options"]["data"] == trained["data"]
    assert (args.steps, args.batch, args.lr, args.seed) == (
        trained["steps"],
        trained["batch"],
        trained["lr"],
        trained["seed"],
    )
    assert args.func.__name__ == "run_pretrain"


def test_options_on_the_command_line_override_the_recipe_wherever_they_stand(tmp_path):
    config = str(CONFIGS / "emma-lwm.json")
    for argv in (
        ["train", "--lr", "0.5", "--config", config, "--data", str(tmp_path), "--no-cosine"],
        ["train", "--data", str(tmp_path), "--no-cosine", f"--config={config}", "--lr=0.5"],
    ):
        args = _parse(argv)
        assert (args.lr, args.cosine, args.kind, args.steps) == (0.5, False, "emma", 60_000)


def test_without_a_recipe_the_command_line_is_unchanged():
    parser = cli_main.build_parser([])
    argv = ["train", "--data", "d", "--out", "r"]
    assert recipes.expand(parser, argv) == argv


def _write(tmp_path: Path, text: str) -> str:
    path = tmp_path / "recipe.json"
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "no such recipe file"),
        ('{"command": "lwm train", "options": {"lr": 0.1,}}', "not JSON"),
        ('["lwm train"]', "a recipe is a JSON object"),
        ('{"command": "lwm train", "options": {}, "flags": 1}', "unknown key(s) flags"),
        ('{"command": "lwm train", "options": {"learning_rate": 0.1}}', "has no option 'learning_rate'"),
        ('{"command": "lwm train", "options": {"lr": -1}}', "option 'lr': must be > 0, got -1"),
        ('{"command": "lwm train", "options": {"steps": 1.5}}', "option 'steps': must be an integer"),
        ('{"command": "lwm train", "options": {"kind": "emmma"}}', "option 'kind': 'emmma' is not one of"),
        ('{"command": "lwm train", "options": {"cosine": "yes"}}', "option 'cosine' must be true or false"),
        ('{"command": "lwm agent pretrain", "options": {}}', "a recipe for `lwm agent pretrain`, not for `lwm train`"),
    ],
)
def test_a_bad_recipe_is_one_line_and_status_2(tmp_path, capsys, content, message):
    path = str(tmp_path / "missing.json") if content is None else _write(tmp_path, content)
    assert cli_main.main(["train", "--config", path, "--data", str(tmp_path), "--out", "r"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"lwm train: error: {path}") and message in err, err
    assert len(err.splitlines()) == 1


def test_a_bad_recipe_exits_2_without_a_traceback(tmp_path):
    path = _write(tmp_path, '{"command": "lwm train", "options": {"lr": "fast"}}')
    done = subprocess.run(
        [sys.executable, "-m", "lwm_models.cli.main", "train", "--config", path],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert done.stderr == f"lwm train: error: {path}: option 'lr': must be a number, got 'fast'\n"
