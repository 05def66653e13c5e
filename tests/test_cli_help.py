"""Every command's --help as a terminal shows it, narrow or wide: flags without a value type (they take none)
and every URL of the help text whole (rich cuts a word longer than its column with an ellipsis)."""

from __future__ import annotations

import re

import pytest
import typer
from typer.testing import CliRunner

from msa_slam.cli import app

URL = re.compile(r"(?:https?://|www\.|github\.com/)[^\s)'\",;]+")
GROUP = typer.main.get_command(app)
COMMANDS = ["", *GROUP.commands]  # "": msa-slam --help itself


def _help_source(name: str) -> str:
    """The help texts --help renders for `name`: the command's, every option's and the closing paragraphs."""
    command = GROUP.commands[name] if name else GROUP
    return "\n".join(
        [command.help or "", *(getattr(p, "help", None) or "" for p in command.params), command.epilog or ""]
    )


@pytest.mark.parametrize("columns", ["80", "200"])
@pytest.mark.parametrize("name", COMMANDS)
def test_help_shows_flags_without_a_type_and_urls_whole(name, columns):
    result = CliRunner().invoke(app, [*([name] if name else []), "--help"], env={"COLUMNS": columns})
    assert result.exit_code == 0, result.output
    assert max(len(line) for line in result.output.splitlines()) == int(columns)  # rendered at that width
    assert "<bool>" not in result.output
    assert re.search(r"--help\s+Show this message", result.output)  # the help flag too: no type between
    for url in URL.findall(_help_source(name)):
        assert url in result.output, f"{url} cut"
