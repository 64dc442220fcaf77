"""tools/dependency_floors.txt pins each of pyproject's dependencies at its floor, so the set
the suite is checked on is the one pyproject promises to work with."""

import pytest
from packaging.requirements import Requirement
from packaging.version import Version

from relaygs import paths

FLOORS = paths.REPO_ROOT / "tools" / "dependency_floors.txt"


def _pins() -> dict[str, Version]:
    """The floors file's `name==version` lines by package name."""
    pins = {}
    for line in FLOORS.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            requirement = Requirement(line)
            (specifier,) = requirement.specifier
            assert specifier.operator == "==", line
            pins[requirement.name] = Version(specifier.version)
    return pins


def _floor(requirement: Requirement) -> Version:
    """The version after `>=` in a dependency's specifier (every dependency has one)."""
    (floor,) = [Version(s.version) for s in requirement.specifier if s.operator == ">="]
    return floor


@pytest.mark.skipif(not FLOORS.is_file(), reason="needs the repository's tools/")
def test_each_dependency_is_pinned_at_its_floor_release(pyproject):
    requirements = {r.name: r for r in map(Requirement, pyproject["project"]["dependencies"])}
    pins = _pins()
    assert sorted(pins) == sorted(requirements)
    for name, requirement in requirements.items():
        assert pins[name] == _floor(requirement), (name, str(pins[name]))
