"""The package's layers, checked from the source (ast: no import, milliseconds) and, for files
read at import time, by importing every stage and the training machinery in a fresh Python."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from functools import cache
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

import pytest

import relaygs

PACKAGE = Path(relaygs.__file__).parent


@cache
def modules() -> dict[str, Path]:
    """Every module of relaygs by dotted name (a package by its own name)."""
    found = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        found[".".join(part for part in parts if part != "__init__")] = path
    return found


def imported(name: str) -> set[str]:
    """The relaygs modules `name` imports anywhere (`TYPE_CHECKING` blocks too: a hidden circle
    is a circle), with the parent packages Python runs first (its own only when it uses them)."""
    path = modules()[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            submodules = [f"{base}.{alias.name}" for alias in node.names]
            targets = [full for full in submodules if full in modules()]
            if len(targets) < len(submodules):
                found.add(base)  # names taken from `base` itself: its __init__ must be done
        else:
            continue
        for target in targets:
            parts = target.split(".")
            found.update(
                ".".join(parts[:end])
                for end in range(2, len(parts) + 1)
                if not name.startswith(".".join(parts[:end]) + ".")
            )
    return {module for module in found if module in modules() and module != name}


def test_no_module_imports_itself_back_through_others():
    try:
        TopologicalSorter({name: imported(name) for name in modules()}).prepare()
    except CycleError as error:
        pytest.fail(f"import circle: {' -> '.join(error.args[1])}")


LOWER_LAYERS = [
    ("relaygs.data", ("cli", "app", "commands", "stages", "train")),
    ("relaygs.train", ("cli", "app", "commands", "stages")),
    ("relaygs.stages", ("cli", "app", "commands")),
    ("relaygs.pipeline", ("cli", "app", "commands", "stages", "train")),
]


@pytest.mark.parametrize(("layer", "above"), LOWER_LAYERS)
def test_a_layer_imports_nothing_above_it(layer, above):
    forbidden = tuple(f"relaygs.{package}" for package in above)
    upward = {
        name: sorted(target for target in imported(name) if target.startswith(forbidden))
        for name in modules()
        if name == layer or name.startswith(layer + ".")
    }
    assert {name: targets for name, targets in upward.items() if targets} == {}


def test_the_layer_check_sees_a_hidden_circle(tmp_path, monkeypatch):
    # the relay ↔ relay_seed circle this guards against was kept alive by TYPE_CHECKING
    (tmp_path / "one.py").write_text("from relaygs.two import x\n")
    guarded = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from relaygs.one import y\n"
    (tmp_path / "two.py").write_text(guarded)
    fake = {**modules(), "relaygs.one": tmp_path / "one.py", "relaygs.two": tmp_path / "two.py"}
    monkeypatch.setattr(sys.modules[__name__], "modules", lambda: fake)
    assert imported("relaygs.one") == {"relaygs.two"}
    assert imported("relaygs.two") == {"relaygs.one"}
    with pytest.raises(pytest.fail.Exception, match=r"relaygs\.one"):
        test_no_module_imports_itself_back_through_others()


READS_AT_IMPORT = """
import builtins, io, json, sys
opened = []
real_open = builtins.open
def spy(file, *args, **kwargs):
    opened.append(str(file))
    return real_open(file, *args, **kwargs)
builtins.open = io.open = spy
import relaygs.stages, relaygs.train.budgets, relaygs.train.error_split, relaygs.app.suite
print(json.dumps([path for path in opened if path.endswith((".yaml", ".yml", ".json"))]))
"""


def test_importing_the_stages_reads_no_config_file():
    # budgets used to read conf/budget/*.yaml when relaygs.stages was imported
    ran = subprocess.run(
        [sys.executable, "-c", READS_AT_IMPORT], capture_output=True, text=True, check=True
    )
    assert json.loads(ran.stdout.splitlines()[-1]) == []
