"""The trajectory dataset: generation, format, reader, replay, and the CLI around it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lwm_models.data.dataset import TrajectoryDataset, generate_dataset
from lwm_models.errors import DatasetError
from lwm_models.messenger import POLICIES, MessengerEnv, compact_to_grid
from lwm_models.messenger.constants import SPLITS
from lwm_models.text import DescriptionPools

LWM = [sys.executable, "-m", "lwm_models.cli.main"]


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds")
    index = generate_dataset(out, DescriptionPools.generated(), max_games=8, train_episodes_per_game=7)
    return out, index


def test_counts_and_policies(small):
    out, index = small
    assert index["splits"]["train"]["episodes"] == 8 * 7
    for split in SPLITS[1:]:
        ds = TrajectoryDataset(out, split)
        assert len(ds) == 8 * len(POLICIES)
        assert sorted(np.bincount(ds.episode_policies).tolist()) == [8] * len(POLICIES)
    assert json.loads((out / "index.json").read_text())["format"] == "messenger-wm-trajectories"


def test_episodes_replay_in_the_real_game(small):
    out, _ = small
    ds = TrajectoryDataset(out, "newall-test")
    for e in range(0, len(ds), 7):
        ep = ds[e]
        env = MessengerEnv(ep.game)
        obs, _ = env.reset(seed=ep.seed)
        np.testing.assert_array_equal(obs, ep.grids[0])
        for t in range(1, len(ep.actions)):
            obs, r, term, trunc, _ = env.step(int(ep.actions[t]))
            np.testing.assert_array_equal(obs, ep.grids[t])
            assert r == ep.rewards[t] and (term or trunc) == ep.dones[t]
        assert ep.dones[-1] and not ep.dones[:-1].any()


def test_manuals_come_from_the_split_pool_and_match_the_parse(small):
    out, _ = small
    pools = DescriptionPools.generated()
    for split in ("train", "newattr-dev"):
        ds = TrajectoryDataset(out, split)
        for e in range(len(ds)):
            ep = ds[e]
            assert sorted(ep.parse) == sorted(ep.game.triples)
            for text, triple in zip(ep.manual, ep.parse):
                assert text in pools.pool(split, triple)


def test_generation_is_seeded(small, tmp_path):
    out, _ = small
    again = tmp_path / "again"
    generate_dataset(again, DescriptionPools.generated(), max_games=8, train_episodes_per_game=7)
    for name in ("observations.npy", "manuals.npy", "episode_seeds.npy"):
        assert (out / "train" / name).read_bytes() == (again / "train" / name).read_bytes()


def test_reader_errors(small, tmp_path):
    out, _ = small
    with pytest.raises(DatasetError, match="no index.json"):
        TrajectoryDataset(tmp_path, "train")
    with pytest.raises(DatasetError, match="not in"):
        TrajectoryDataset(out, "valid")
    broken = tmp_path / "broken"
    broken.mkdir()
    for item in out.iterdir():
        target = broken / item.name
        if item.is_dir():
            target.mkdir()
            for f in item.iterdir():
                target.joinpath(f.name).write_bytes(f.read_bytes())
        else:
            target.write_bytes(item.read_bytes())
    obs = np.load(broken / "train" / "observations.npy")
    np.save(broken / "train" / "observations.npy", obs[:-5])
    with pytest.raises(DatasetError, match="do not match"):
        TrajectoryDataset(broken, "train")


def test_grids_round_trip(small):
    out, _ = small
    ep = TrajectoryDataset(out, "train")[0]
    assert compact_to_grid(ep.observations).shape == (len(ep.observations), 10, 10, 4)


def test_cli_splits_and_generate(tmp_path):
    proc = subprocess.run(LWM + ["data", "splits"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "train" in proc.stdout and "1536" in proc.stdout and "expected" not in proc.stdout
    out = tmp_path / "d"
    proc = subprocess.run(
        LWM + ["data", "generate", "--out", str(out), "--max-games", "2", "--episodes-per-game", "2", "--no-progress"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["splits"]["train"]["episodes"] == 4


@pytest.mark.parametrize(
    "argv, message",
    [
        (["data", "generate", "--out", "x", "--episodes-per-game", "0"], "must be >= 1"),
        (["data", "generate", "--out", "{tmp}/y", "--text-source", "{tmp}/missing.json"], "missing.json"),
    ],
)
def test_cli_bad_input_is_a_message_not_a_traceback(argv, message, tmp_path):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    proc = subprocess.run(LWM + argv, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert message in proc.stderr and "Traceback" not in proc.stderr


def test_human_text_source(tmp_path):
    texts = Path(__file__).resolve().parents[2] / "shared" / "data" / "messenger-texts"
    if not texts.is_dir():
        pytest.skip("shared human-written descriptions not available")
    files = [texts / "text_train.json", texts / "text_val.json"]
    pools = DescriptionPools.from_files(files)
    index = generate_dataset(tmp_path, pools, max_games=3, train_episodes_per_game=2, text_source="human")
    ds = TrajectoryDataset(tmp_path, "newall-test")
    assert index["text_source"] == "human" and len(ds.texts) > 0 and ds.human_written
    human = set()
    for f in files:
        data = json.loads(f.read_text())
        for roles in data.values():
            for movs in roles.values():
                for lst in movs.values():
                    human.update(lst)
    used = set(ds.texts)
    assert len(used & human) / len(used) > 0.8


@pytest.mark.parametrize("benchmark", ["language_robustness.py", "read_back.py"])
def test_benchmarks_refuse_the_generators_text_as_the_dataset(small, benchmark):
    # A directory generated without --text-source holds the generator's descriptions: measured as
    # "the dataset's", they would be the generator's text under the dataset's name.
    out, _index = small
    root = Path(__file__).resolve().parents[1]
    argv = [sys.executable, str(root / "benchmarks" / benchmark), "--data", str(out), "--models", "observational"]
    refused = subprocess.run([*argv, "--sources", "dataset"], capture_output=True, text=True, timeout=120)
    assert refused.returncode != 0
    assert "holds the generator's descriptions" in refused.stderr and "Traceback" not in refused.stderr
    assert not TrajectoryDataset(out, "newall-test").human_written
