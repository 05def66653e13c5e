"""The console entry point: bad input ends with one clear line and exit code 2, usage errors with click's."""

from __future__ import annotations

import subprocess
import sys

from helpers.cli import run_cli


def test_input_error_is_one_line_without_traceback(tmp_path):
    result = run_cli("sample", "--poses", str(tmp_path / "missing.txt"), "--descriptors", "d.npy", "--quiet")
    assert result.returncode == 2
    assert result.stderr.strip() == f"error: {tmp_path / 'missing.txt'}: pose file not found"


def test_usage_error_names_the_missing_option():
    result = run_cli("sample", "--descriptors", "d.npy")
    assert result.returncode == 2
    assert "Missing option '--poses'" in result.stderr and "Traceback" not in result.stderr


HEAVY = (
    "numpy",
    "scipy",
    "gtsam",
    "matplotlib",
    "trimesh",
    "embreex",
    "torch",
    "dask",
    "kiss_icp",
    "small_gicp",
    "pydantic",
    "yaml",
)


def test_help_imports_no_heavy_library():
    code = (
        "import sys; from msa_slam.cli import main; sys.argv = ['msa-slam', '--help']\n"
        "try:\n    main()\nexcept SystemExit:\n    pass\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "Usage: msa-slam" in result.stdout
    assert result.stdout.strip().splitlines()[-1] == "[]"


def test_version_prints_the_package_version():
    from msa_slam import __version__

    result = run_cli("--version")
    assert result.returncode == 0
    assert result.stdout.strip() == f"msa-slam {__version__}"


def test_sampler_names_in_help_are_the_registry():
    from msa_slam.cli.options import SAMPLER_NAMES
    from msa_slam.sampling.registry import SAMPLERS

    assert SAMPLER_NAMES == tuple(SAMPLERS)


def test_no_library_module_imports_the_cli():
    import ast
    from pathlib import Path

    import msa_slam

    root = Path(msa_slam.__file__).parent
    offenders = []
    for path in root.rglob("*.py"):
        if path.is_relative_to(root / "cli"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            offenders += [f"{path.relative_to(root)}: {n}" for n in names if n.split(".")[:2] == ["msa_slam", "cli"]]
    assert offenders == []


def test_importing_one_module_does_not_import_its_package_siblings():
    code = (
        "import sys, msa_slam.experiments.grid, msa_slam.evaluation.display, msa_slam.sampling.params\n"
        "print(sorted(m for m in ('matplotlib', 'evo', 'scipy', 'gtsam') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.stdout.strip() == "[]", result.stderr


def test_lazy_package_exports_resolve_and_unknown_names_fail():
    import pytest

    import msa_slam.evaluation as evaluation
    import msa_slam.sampling as sampling
    from msa_slam.sampling.registry import make_sampler

    assert sampling.make_sampler is make_sampler and "make_sampler" in dir(sampling)
    assert callable(evaluation.ate)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        sampling.nope


def test_permission_error_is_one_line_without_traceback(monkeypatch, capsys):
    import pytest

    import msa_slam.cli as cli

    def unreadable() -> None:  # what reading a chmod-000 scan raises deep inside a loader
        raise PermissionError(13, "Permission denied", "/data/seq/velodyne/000007.bin")

    monkeypatch.setattr(cli, "app", unreadable)
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    assert exit_info.value.code == 2
    assert capsys.readouterr().err == (
        "error: /data/seq/velodyne/000007.bin: permission denied (check its permissions)\n"
    )
