"""The examples in the public modules' docstrings run (and stay true)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import dexmots_rl


def _modules_with_examples() -> list[str]:
    names = []
    for info in pkgutil.walk_packages(dexmots_rl.__path__, prefix="dexmots_rl."):
        if info.name.startswith("dexmots_rl.configs"):
            continue
        module = importlib.import_module(info.name)
        finder = doctest.DocTestFinder(exclude_empty=True)
        if any(t.examples for t in finder.find(module)):
            names.append(info.name)
    return names


MODULES = _modules_with_examples()


def test_modules_have_examples():
    assert {"dexmots_rl.envs.registry", "dexmots_rl.envs.config", "dexmots_rl.sim"} <= set(MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
