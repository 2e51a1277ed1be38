"""Every console command the README prints parses as printed.

The shell commands of the README's code blocks that start with a ``dexmots-*`` script are checked in process,
without running them: the hydra apps (``dexmots-train``, ``dexmots-table``, ``dexmots-record``) compose their
config with ``--cfg job`` appended, the argparse apps parse their arguments (the parser is stopped right after it
accepts them).
"""

from __future__ import annotations

import argparse
import importlib
import re
import shlex
import sys
import tomllib
from pathlib import Path

import pytest

from dexmots_rl.envs import list_tasks

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
HYDRA_APPS = {"dexmots-train", "dexmots-table", "dexmots-record"}


def console_scripts() -> dict[str, str]:
    """``{"dexmots-train": "dexmots_rl.apps.train:main", ...}`` from pyproject.toml."""
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["project"]["scripts"]


def readme_commands() -> list[list[str]]:
    """The README's ``dexmots-*`` shell commands as argv lists (continuation lines joined, comments and leading
    ``VAR=value`` assignments dropped)."""
    text = README.read_text()
    commands = []
    for block in re.findall(r"```(?:bash|sh|shell)\n(.*?)```", text, re.S):
        for line in block.replace("\\\n", " ").splitlines():
            argv = shlex.split(line, comments=True)
            while argv and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*=.*", argv[0]):
                argv = argv[1:]
            if argv and argv[0].startswith("dexmots-"):
                commands.append(argv)
    return commands


COMMANDS = readme_commands()


def test_readme_shows_every_console_script():
    shown = {argv[0] for argv in COMMANDS}
    missing = sorted(set(console_scripts()) - shown)
    assert not missing, f"README has no example command for {missing}"


def test_readme_names_only_real_scripts():
    unknown = sorted({argv[0] for argv in COMMANDS} - set(console_scripts()))
    assert not unknown, f"README shows commands that pyproject.toml does not install: {unknown}"


class _Parsed(Exception):
    """Raised by the patched ``parse_args`` once the app's parser accepted the arguments."""


def _entry_point(script: str):
    module, _, func = console_scripts()[script].partition(":")
    return getattr(importlib.import_module(module), func)


@pytest.mark.parametrize("argv", COMMANDS, ids=[" ".join(a)[:80] for a in COMMANDS])
def test_readme_command_parses(argv, monkeypatch, capsys):
    script, args = argv[0], argv[1:]
    main = _entry_point(script)
    if script in HYDRA_APPS:
        from hydra.core.global_hydra import GlobalHydra

        GlobalHydra.instance().clear()  # another test's compose() may have left hydra initialised
        monkeypatch.setattr(sys, "argv", [script, *args, "--cfg", "job"])
        try:
            main()
        except SystemExit as exc:  # hydra exits non-zero on a bad override or a config it cannot compose
            pytest.fail(f"{' '.join(argv)}: hydra refused it (exit {exc.code}):\n{capsys.readouterr().err}")
        assert capsys.readouterr().out.strip(), f"{' '.join(argv)}: --cfg job printed no config"
    else:
        original = argparse.ArgumentParser.parse_args

        def parse_then_stop(self, *a, **k):
            namespace = original(self, *a, **k)
            raise _Parsed(namespace)

        monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
        with pytest.raises(_Parsed):
            try:
                main(args)
            except SystemExit as exc:  # argparse's error exit
                pytest.fail(f"{' '.join(argv)}: the parser refused it (exit {exc.code}):\n{capsys.readouterr().err}")


def _task_table_rows() -> dict[str, str]:
    """The README task table's rows by task name (the first cell, `name`)."""
    rows = re.findall(r"^\| `(\w+)` \| (.*)$", README.read_text(), re.M)
    return {name: rest for name, rest in rows}


@pytest.mark.parametrize("task", list_tasks())
def test_the_task_table_has_a_row_for_every_registered_task(task):
    """Every task a user can train has a row; a trained one says how it did and links the measurement."""
    rows = _task_table_rows()
    assert task in rows, f"README's task table lacks {task}"
    assert task == "operate" or "](docs/results.md#" in rows[task], rows[task]


@pytest.mark.parametrize("page, most", [("README.md", 600), ("docs/results.md", 500)])
def test_guide_and_results_stay_a_page(page, most):
    """The README is a guide and docs/results.md a page of current figures (superseded ones live in git)."""
    lines = (Path(__file__).resolve().parents[1] / page).read_text().count("\n")
    assert lines <= most, f"{page} has {lines} lines (at most {most}): move detail to docs/ or drop superseded figures"
