"""Every test file carries markers (test/conftest.py FILE_MARKERS, registered in setup.cfg), so that `-m` selects a part
of the suite: the fast subset `-m "(unit or engine) and not slow"` is documented in README.md and setup.cfg."""
from __future__ import annotations

import configparser
from pathlib import Path

from conftest import FILE_MARKERS

TEST_DIR = Path(__file__).resolve().parent
KINDS = {"unit", "engine", "data", "ros"}  # what a test needs; "slow" is added to those


def test_every_test_file_has_markers_and_every_entry_a_file():
    files = {p.name for p in TEST_DIR.glob("test_*.py")}
    assert sorted(files - set(FILE_MARKERS)) == [], "test files without markers: add them to FILE_MARKERS"
    assert sorted(set(FILE_MARKERS) - files) == [], "FILE_MARKERS names files that do not exist"


def test_every_file_says_what_it_needs_with_registered_markers():
    config = configparser.ConfigParser()
    config.read(TEST_DIR.parent / "setup.cfg")
    registered = {line.split(":")[0].strip() for line in config["tool:pytest"]["markers"].strip().splitlines()}
    assert KINDS | {"slow"} <= registered
    for name, markers in FILE_MARKERS.items():
        assert set(markers) <= registered, (name, markers)
        assert KINDS & set(markers), f"{name}: none of {sorted(KINDS)}"
