"""The version a user sees is the one the release declares."""

from __future__ import annotations

import tomllib
from pathlib import Path

import chargax_marl
from chargax_marl.benchmark.references import package_version

ROOT = Path(__file__).resolve().parents[1]


def _declared() -> str:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def test_version_is_pyprojects():
    assert chargax_marl.__version__ == _declared()


def test_reference_files_record_the_same_version():
    assert package_version() == chargax_marl.__version__


def test_the_changelog_has_a_section_for_the_version():
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert f"## [{_declared()}] - " in changelog
    assert changelog.index("## [Unreleased]") < changelog.index(f"## [{_declared()}]")
