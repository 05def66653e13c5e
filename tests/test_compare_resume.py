"""`compare --seeds` resumes after an interruption: finished seeds are kept and reused, never recomputed, a
folder whose finished seeds were run with other settings is refused, and a finished seed whose data or code
changed since it ran is rerun (msa_slam.experiments.seed_folder).

Two methods on a 60-scan prefix of the simulated figure-eight (coarse azimuth: at 180 steps the odometry of
seed 1 stalls and MSA keeps too few keyframes), without figures (what is resumed is the same with them): a seed
costs a few seconds.
"""

from __future__ import annotations

import json
import shutil

import pytest
import yaml

import msa_slam.experiments.compare as compare
import msa_slam.experiments.identity as identity
import msa_slam.slam.backend as backend
from msa_slam.experiments.compare import method_configs, run_compare
from msa_slam.experiments.seed_folder import seed_identities
from msa_slam.experiments.seeds import seeded_datasets
from msa_slam.io import staging
from msa_slam.io.outputs import MARKER, OutputError, write_marker
from msa_slam.pipeline import make_config

METHODS = (("all", "all", {}), ("msa", "msa", {}))
SEEDS = [0, 1]


def _no_rss_growth(patch: pytest.MonkeyPatch) -> None:
    """The process's RSS growth, the one figure of seeds.json that differs between two runs of the same command,
    pinned to 0 so whole files can be compared."""
    patch.setattr(backend, "current_rss_bytes", lambda: 0)


@pytest.fixture(scope="module")
def base(cache_dir):
    return make_config(dataset="sim:test,end=60,azimuth_steps=360", cache_dir=str(cache_dir))


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
    return run_compare(base, out, methods=METHODS, seeds=SEEDS, figures=False, **kwargs)


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
    (seeds / ".seed-1.partial-killed").mkdir()  # what a SIGKILL inside seed 1 leaves: its writer's stamp
    (seeds / ".seed-1.partial-killed" / staging.WRITER).write_bytes(staging.stamp())

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

    run_compare(changed, out, methods=METHODS, seeds=[0], overwrite=True, figures=False)
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
        refused.value
    )
    assert calls == []

    run_compare(windowed, out, methods=METHODS, seeds=[0], overwrite=True, figures=False)
    assert calls == [0]
    used = {
        m: yaml.safe_load((out / "seeds" / "seed-0" / "runs" / m / "config.yaml").read_text())["sampler_params"]
        for m in ("all", "msa")
    }
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


RERUN_NOTE = "\nSeeds rerun by this run, their earlier results replaced:\n\n"
OTHER_CODE = "c0de" * 16  # what the fingerprint of msa-slam's code is after an edit


def _seed_json(out, seed: int) -> dict:
    return json.loads((out / "seeds" / f"seed-{seed}" / "seed.json").read_text())


def _warnings(caplog) -> list[str]:
    """What compare itself warned about (the front end may warn about odometry on a cold cache)."""
    return [r.getMessage() for r in caplog.records if r.name == compare.__name__]


def _without_rerun_note(report: str) -> str:
    """report.md as a run that reran nothing writes it: the list of rerun seeds taken out."""
    head, note, tail = report.partition(RERUN_NOTE)
    return head + tail.partition("\n\n")[2] if note else report


def test_finished_seeds_record_their_identity_and_are_reused_while_it_holds(
    base, whole, calls, tmp_path, capsys, caplog
):
    plans = {
        s: method_configs(make_config({**base.dump(), "dataset": d}), METHODS)
        for s, d in zip(SEEDS, seeded_datasets(base.dataset, SEEDS))
    }
    current = seed_identities(plans)
    assert current[0]["code"] == current[1]["code"] and current[0]["data"] != current[1]["data"]  # the world seed
    assert {s: _seed_json(whole, s)["identity"] for s in SEEDS} == current
    out = tmp_path / "cmp"
    shutil.copytree(whole, out)
    _run(base, out, quiet=False)
    assert calls == [] and not _warnings(caplog)
    err = capsys.readouterr().err
    assert "seed 0: reused" in err and "seed 1: reused" in err
    for name in ("seeds.json", "seeds.csv", "seeds.md", "report.md"):
        assert (out / name).read_bytes() == (whole / name).read_bytes(), name


def test_a_code_change_reruns_every_seed(base, whole, calls, monkeypatch, tmp_path, caplog):
    out = tmp_path / "cmp"
    shutil.copytree(whole, out)
    monkeypatch.setattr(identity, "code_fingerprint", lambda modules, data=(), package_dir=None: OTHER_CODE)
    _run(base, out)
    assert calls == SEEDS
    lines = [f"seed {s}: its code changed since it ran; rerun" for s in SEEDS]
    assert _warnings(caplog) == [f"compare: {line}" for line in lines]
    report = (out / "report.md").read_text()
    assert RERUN_NOTE + "".join(f"- {line}\n" for line in lines) in report
    assert _without_rerun_note(report) == (whole / "report.md").read_text()  # what a cold run writes
    for name in ("seeds.json", "seeds.csv", "seeds.md"):
        assert (out / name).read_bytes() == (whole / name).read_bytes(), name
    assert {_seed_json(out, s)["identity"]["code"] for s in SEEDS} == {OTHER_CODE[:24]}
    assert sorted(p.name for p in (out / "seeds").iterdir()) == ["seed-0", "seed-1"]  # nothing left aside

    calls.clear()
    caplog.clear()
    _run(base, out)  # the same code again: reused, and the report says nothing of reruns
    assert calls == [] and not _warnings(caplog)
    assert (out / "report.md").read_bytes() == (whole / "report.md").read_bytes()


def test_only_the_seed_whose_data_changed_is_rerun(base, whole, calls, monkeypatch, tmp_path, caplog):
    out = tmp_path / "cmp"
    shutil.copytree(whole, out)
    real = identity.dataset_identity

    def seed_1_changed(config, cache):
        found = real(config, cache)
        return {**found, "edited": True} if config["dataset"].endswith("seed=1") else found

    monkeypatch.setattr(identity, "dataset_identity", seed_1_changed)
    _run(base, out)
    assert calls == [1] and _warnings(caplog) == ["compare: seed 1: its data changed since it ran; rerun"]
    assert (out / "seeds.json").read_bytes() == (whole / "seeds.json").read_bytes()


def test_a_seed_of_the_previous_format_is_rerun(base, whole, calls, tmp_path, caplog):
    out = tmp_path / "cmp"
    shutil.copytree(whole, out)
    old = {k: v for k, v in _seed_json(out, 0).items() if k != "identity"}  # as msa-slam wrote it before
    (out / "seeds" / "seed-0" / "seed.json").write_text(json.dumps(old))
    write_marker(out, "compare")
    _run(base, out)
    assert calls == [0]
    assert _warnings(caplog) == [
        "compare: seed 0: it records no identity of its data and code (an older msa-slam ran it); rerun"
    ]
    assert _seed_json(out, 0)["identity"] == _seed_json(whole, 0)["identity"]
    assert (out / "seeds.json").read_bytes() == (whole / "seeds.json").read_bytes()


def test_a_seed_to_rerun_holding_someone_elses_files_is_refused(base, whole, calls, monkeypatch, tmp_path):
    out = tmp_path / "cmp"
    shutil.copytree(whole, out)
    (out / "seeds" / "seed-1" / "notes.txt").write_text("mine")
    monkeypatch.setattr(identity, "code_fingerprint", lambda modules, data=(), package_dir=None: OTHER_CODE)
    with pytest.raises(OutputError) as refused:
        _run(base, out)
    message = str(refused.value)
    assert "\n" not in message and "seed 1: its code changed since it ran, but its folder holds files" in message
    assert "seeds/seed-1/notes.txt" in message and "move them out" in message
    assert calls == [] and (out / "seeds" / "seed-1" / "notes.txt").read_text() == "mine"
    assert _seed_json(out, 0) == _seed_json(whole, 0)  # no seed removed
