"""`compare --seeds` resumes after an interruption: finished seeds are kept and reused, never recomputed, and a
folder whose finished seeds were run with other settings is refused (msa_slam.pipeline.seed_folder).

Two methods on a 30-scan prefix of the simulated figure-eight (coarse azimuth): a seed costs about 2 s.
"""

from __future__ import annotations

import json
import shutil

import pytest
import yaml

import msa_slam.pipeline.compare as compare
import msa_slam.slam.backend as backend
from msa_slam.io.outputs import MARKER, OutputError, write_marker
from msa_slam.pipeline import make_config
from msa_slam.pipeline.compare import run_compare

METHODS = (("all", "all", {}), ("msa", "msa", {}))
SEEDS = [0, 1]


def _no_rss_growth(patch: pytest.MonkeyPatch) -> None:
    """The process's RSS growth, the one figure of seeds.json that differs between two runs of the same command,
    pinned to 0 so whole files can be compared."""
    patch.setattr(backend, "current_rss_bytes", lambda: 0)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    cache = tmp_path_factory.mktemp("compare-resume-cache")
    return make_config(dataset="sim:test,end=60,azimuth_steps=360", cache_dir=str(cache))


@pytest.fixture(scope="module")
def whole(base, tmp_path_factory):
    """The same comparison run without interruption."""
    out = tmp_path_factory.mktemp("whole") / "cmp"
    with pytest.MonkeyPatch.context() as patch:
        _no_rss_growth(patch)
        _run(base, out)
    return out


@pytest.fixture
def calls(monkeypatch):
    """The seeds whose comparison is computed, in order."""
    _no_rss_growth(monkeypatch)
    done: list[int] = []
    real = compare._comparison

    def counting(configs, tmp, *args):
        done.append(int(configs[0].dataset.rsplit("seed=", 1)[1]))
        return real(configs, tmp, *args)

    monkeypatch.setattr(compare, "_comparison", counting)
    return done


def _run(base, out, **kwargs):
    return run_compare(base, out, methods=METHODS, seeds=SEEDS, **kwargs)


def _interrupt_on_seed_1(monkeypatch):
    """Seed 1's work writes part of its folder, then dies (as a crash or Ctrl-C would)."""
    real = compare._comparison

    def failing(configs, tmp, *args):
        if configs[0].dataset.endswith("seed=1"):
            (tmp / "comparison.md").write_text("half")
            raise KeyboardInterrupt
        return real(configs, tmp, *args)

    monkeypatch.setattr(compare, "_comparison", failing)


def test_an_interrupted_run_resumes_reusing_finished_seeds(base, whole, calls, monkeypatch, tmp_path, capsys):
    out = tmp_path / "resumed"
    with monkeypatch.context() as patch:
        _interrupt_on_seed_1(patch)
        with pytest.raises(KeyboardInterrupt):
            _run(base, out)
    seeds = out / "seeds"
    assert sorted(p.name for p in seeds.iterdir()) == ["seed-0"]  # no half-written seed 1
    assert {"seed.json", "comparison.json", "report.md"} <= {p.name for p in (seeds / "seed-0").iterdir()}
    assert not (out / "seeds.json").exists()
    assert calls == [0]
    (seeds / ".seed-1.partial-killed").mkdir()  # what a SIGKILL inside seed 1 leaves

    calls.clear()
    _run(base, out, quiet=False)
    assert calls == [1]  # seed 0 was not recomputed
    assert "seed 0: reused" in capsys.readouterr().err
    assert sorted(p.name for p in seeds.iterdir()) == ["seed-0", "seed-1"]
    for name in ("seeds.json", "seeds.csv", "seeds.md", "report.md"):
        assert (out / name).read_bytes() == (whole / name).read_bytes(), name

    calls.clear()
    _run(base, out)  # a finished folder: every seed reused, the spread rewritten
    assert calls == []
    assert (out / "seeds.json").read_bytes() == (whole / "seeds.json").read_bytes()


def test_other_settings_are_refused_and_overwrite_replaces(base, whole, calls, tmp_path):
    out = tmp_path / "cmp"
    shutil.copytree(whole, out)
    before = (out / "seeds" / "seed-0" / "seed.json").read_bytes()
    changed = make_config({**base.dump(), "similarity_threshold": 0.7})
    calls.clear()
    with pytest.raises(OutputError) as refused:
        run_compare(changed, out, methods=METHODS, seeds=[0])
    message = str(refused.value)
    assert "\n" not in message and "seed 0 was run with other settings" in message
    assert "methods.all.similarity_threshold: 0.8 there, 0.7 now" in message and "--overwrite" in message
    assert calls == [] and (out / "seeds" / "seed-0" / "seed.json").read_bytes() == before

    with pytest.raises(OutputError, match="seed 0 was run with other settings .methods.entropy: absent there"):
        run_compare(base, out, methods=(*METHODS, ("entropy", "entropy", {})), seeds=[0])
    with pytest.raises(OutputError, match="seed 0 was run with other settings .threshold_sweep: true there, false now"):
        run_compare(base, out, methods=METHODS, seeds=[0], sweep=False)

    run_compare(changed, out, methods=METHODS, seeds=[0], overwrite=True)
    assert calls == [0] and sorted(p.name for p in (out / "seeds").iterdir()) == ["seed-0"]  # replaced, not merged
    record = json.loads((out / "seeds" / "seed-0" / "seed.json").read_text())
    assert record["methods"]["msa"]["similarity_threshold"] == 0.7 and record["failed"] == {}
    assert record["dataset"] == base.dataset and "cache_dir" not in record["methods"]["msa"]


def test_sampler_parameters_reach_msa_and_are_settings_a_resume_compares(base, whole, calls, tmp_path):
    out = tmp_path / "cmp"
    shutil.copytree(whole, out)
    windowed = make_config({**base.dump(), "sampler_params": {"window": 8}})  # as -p window=8 gives it
    calls.clear()
    with pytest.raises(OutputError) as refused:
        run_compare(windowed, out, methods=METHODS, seeds=[0])
    assert "seed 0 was run with other settings (methods.msa.sampler_params.window: absent there, 8 now)" in str(
        refused.value)
    assert calls == []

    run_compare(windowed, out, methods=METHODS, seeds=[0], overwrite=True)
    assert calls == [0]
    used = {m: yaml.safe_load((out / "seeds" / "seed-0" / "runs" / m / "config.yaml").read_text())["sampler_params"]
            for m in ("all", "msa")}
    assert used == {"all": {}, "msa": {"window": 8}}
    record = json.loads((out / "seeds" / "seed-0" / "seed.json").read_text())
    assert {m: record["methods"][m]["sampler_params"] for m in ("all", "msa")} == used


def test_a_rerun_with_fewer_seeds_keeps_the_others_out_of_the_spread(base, whole, calls, tmp_path):
    out = tmp_path / "cmp"
    shutil.copytree(whole, out)
    run_compare(base, out, methods=METHODS, seeds=[1])
    assert calls == []
    assert json.loads((out / "seeds.json").read_text())["seeds"] == [1]
    assert "left out of the spread (not among --seeds): [seed 0]" in (out / "report.md").read_text()


def test_folders_that_cannot_be_resumed_are_refused_before_any_work(base, calls, tmp_path):
    users = tmp_path / "users"
    users.mkdir()
    (users / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="not a msa-slam result folder"):
        run_compare(base, users, methods=METHODS, seeds=[0], overwrite=True)
    assert [p.name for p in users.iterdir()] == ["notes.txt"]

    plain = tmp_path / "plain"  # a comparison without --seeds
    plain.mkdir()
    write_marker(plain, "compare")
    (plain / "comparison.md").write_text("| method |\n")
    with pytest.raises(OutputError, match="holds a comparison run without --seeds; pass --overwrite"):
        run_compare(base, plain, methods=METHODS, seeds=[0])

    old = tmp_path / "old"  # a seed finished by a version that kept no record
    (old / "seeds" / "seed-0").mkdir(parents=True)
    write_marker(old, "compare")
    (old / "seeds" / "seed-0" / "comparison.json").write_text("[]")
    with pytest.raises(OutputError, match="seed 0 has no readable record .* pass --overwrite"):
        run_compare(base, old, methods=METHODS, seeds=[0])
    assert calls == [] and sorted(p.name for p in old.iterdir()) == [MARKER, "seeds"]
