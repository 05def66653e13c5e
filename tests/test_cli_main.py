"""The console entry point: bad input ends with one clear line and exit code 2, usage errors with click's."""

from __future__ import annotations

import subprocess
import sys


def run_cli(*args: str) -> subprocess.CompletedProcess:
    code = "import sys; from msa_slam.cli import main; sys.argv = ['msa-slam', *sys.argv[1:]]; main()"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120)


def test_input_error_is_one_line_without_traceback(tmp_path):
    result = run_cli("sample", "--poses", str(tmp_path / "missing.txt"), "--descriptors", "d.npy", "--quiet")
    assert result.returncode == 2
    assert result.stderr.strip() == f"error: {tmp_path / 'missing.txt'}: pose file not found"


def test_usage_error_names_the_missing_option():
    result = run_cli("sample", "--descriptors", "d.npy")
    assert result.returncode == 2
    assert "Missing option '--poses'" in result.stderr and "Traceback" not in result.stderr
