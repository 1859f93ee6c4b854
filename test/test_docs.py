"""The user documentation stays true to the repository: every repository path README.md and docs/*.md name exists,
no lab-notebook references ("session 12", "issue 4") or dated measurements sit in code, config or docs outside
docs/RESULTS.md, whose tables carry their dates in provenance lines, and the README stays short with its sections."""
from __future__ import annotations

import functools
import os
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
SKIP_DIRS = {".git", ".venv", "build", "install", "log", ".pytest_cache", ".hypothesis", "__pycache__"}
TEXT_SUFFIXES = {".py", ".pyi", ".cpp", ".hpp", ".h", ".md", ".yaml", ".yml", ".xml", ".cfg", ".txt", ".sh", ".toml",
                 ".rviz", ""}
# Names whose first component is a top-level entry of the repository are checked as paths relative to its root.
TOP_LEVEL = {p.name for p in ROOT.iterdir() if p.name not in SKIP_DIRS and (not p.name.startswith(".") or p.name == ".ci")}
# A lone source file name in a code span (`odometry.cpp`) must exist somewhere in the repository; a few names are
# other projects' files.
SOURCE_NAME = re.compile(r"^\w[\w.-]*\.(py|pyi|cpp|hpp|h|sh|rviz)$")
NOT_OURS = {"evaluate_odometry.cpp"}  # the KITTI odometry devkit's
NOTEBOOK = re.compile(r"\b(session|issue)s?[ -]?#?[0-9]+", re.IGNORECASE)
DATE = re.compile(r"\b20[0-9]{2}-[01][0-9]-[0-3][0-9]\b(?! [0-9]{2}:[0-9]{2}:)")  # not a data format's stamp
# Files another owner is still cleaning of "session N" / "issue N" (the C++ engine and its bindings). The test fails
# when one of them is clean, so the list only shrinks.
PENDING_NOTEBOOK: set[str] = set()


def _repository_files() -> list[str]:
    """Tracked files (git), else every file under the root outside build and cache directories."""
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, timeout=60, check=True)
        files = [f for f in out.stdout.splitlines() if (ROOT / f).is_file()]
    except (OSError, subprocess.SubprocessError):
        files = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*")
                 if p.is_file() and not SKIP_DIRS.intersection(p.relative_to(ROOT).parts)]
    return [f for f in files if Path(f).suffix in TEXT_SUFFIXES]


def _named_paths(text: str) -> tuple[set[str], set[str]]:
    """(paths from the repository root, bare file names) named in a markdown text: every word of a code span, of a
    shell code block and every link target (other blocks hold examples: manifests, parameter files, diagrams)."""
    spans = re.findall(r"```(?:bash|sh|console)\n.*?```", text, flags=re.DOTALL)
    inline = re.findall(r"`([^`\n]+)`", re.sub(r"```.*?```", "", text, flags=re.DOTALL))
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    rooted, bare = set(), set()
    for word in " ".join([*spans, *inline, *links]).replace("`", " ").split():
        word = word.split("::")[0].strip("\"'(),;:.[]{}<>")
        first = word.split("/")[0]
        if "/" in word and first in TOP_LEVEL:
            rooted.add(word.rstrip("/"))
    for span in inline:  # a lone file name in a code span: `odometry.cpp`, `range_image.*`
        word = span.strip()
        if SOURCE_NAME.match(word) and word not in NOT_OURS:
            bare.add(word)
    return rooted, bare


def _exists(rooted: str) -> bool:
    return any(ROOT.glob(rooted)) if "*" in rooted else (ROOT / rooted).exists()


@functools.lru_cache(maxsize=1)
def _file_names() -> frozenset[str]:
    """The names of the files under the root outside build and cache directories (pruned while walking: .venv alone
    holds tens of thousands)."""
    names = set()
    for _, dirnames, filenames in os.walk(ROOT):
        dirnames[:] = [d for d in dirnames if d not in SKIP_DIRS]
        names.update(filenames)
    return frozenset(names)


def _found_anywhere(name: str) -> bool:
    return name in _file_names()


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_path_a_doc_names_exists(doc: Path):
    rooted, bare = _named_paths(doc.read_text(encoding="utf-8"))
    assert rooted, f"{doc.name} names no repository path: the extraction is broken"
    missing = sorted(p for p in rooted if not _exists(p))
    missing += sorted(n for n in bare if not _found_anywhere(n))
    assert missing == [], f"{doc.relative_to(ROOT)} names paths that do not exist: {missing}"


def test_the_path_check_sees_a_missing_path():
    rooted, bare = _named_paths("see `line_odom/no_such_module.py`, [this](docs/NOPE.md) and `no_such_file.hpp`\n"
                                "```bash\n.venv/bin/python bench/no_such_bench.py --flag\n```\n")
    assert {"line_odom/no_such_module.py", "docs/NOPE.md", "bench/no_such_bench.py"} <= rooted
    assert not any(_exists(p) for p in rooted) and not _found_anywhere(next(iter(bare)))


def _notebook_hits(rel: str) -> list[str]:
    lines = (ROOT / rel).read_text(encoding="utf-8", errors="replace").splitlines()
    provenance = rel == "docs/RESULTS.md"
    return [f"{rel}:{i}: {line.strip()[:100]}" for i, line in enumerate(lines, 1)
            if NOTEBOOK.search(line) and not (provenance and line.startswith("Provenance:"))]


def test_no_session_or_issue_numbers_in_code_config_and_docs():
    this = str(Path(__file__).relative_to(ROOT))
    files = [f for f in _repository_files() if f != this]
    hits = [h for f in files if f not in PENDING_NOTEBOOK for h in _notebook_hits(f)]
    assert hits == [], "lab-notebook references (history belongs in git):\n" + "\n".join(hits)
    clean = sorted(f for f in PENDING_NOTEBOOK if (ROOT / f).exists() and not _notebook_hits(f))
    assert clean == [], f"{clean} no longer mention sessions or issues: take them off PENDING_NOTEBOOK"


def test_no_dated_measurements_outside_results():
    this = str(Path(__file__).relative_to(ROOT))
    skip = {this, "docs/RESULTS.md", "requirements/lock.txt"}
    hits = []
    for rel in _repository_files():
        if rel in skip:
            continue
        for i, line in enumerate((ROOT / rel).read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if DATE.search(line):
                hits.append(f"{rel}:{i}: {line.strip()[:100]}")
    assert hits == [], "dates belong in docs/RESULTS.md's provenance lines:\n" + "\n".join(hits)


def test_every_results_table_has_a_provenance_line():
    sections = re.split(r"^## ", (ROOT / "docs" / "RESULTS.md").read_text(encoding="utf-8"), flags=re.MULTILINE)[1:]
    assert len(sections) >= 12
    for section in sections:
        title = section.splitlines()[0]
        if "|---" not in section or title == "Preset choices":  # the latter: one provenance per setting, inline
            continue
        paragraph = re.search(r"^Provenance: .*?(?=\n\n|\Z)", section, flags=re.MULTILINE | re.DOTALL)
        assert paragraph, f"RESULTS.md section {title!r} has no provenance line"
        text = paragraph.group(0)
        assert re.search(r"`[^`]+`", text), f"{title!r}: the provenance names no command"
        assert re.search(r"\bcommit\s+[0-9a-f]{7,40}\b", text), f"{title!r}: the provenance names no commit"
        assert re.search(r"\b20[0-9]{2}-[01][0-9]-[0-3][0-9]\b", text), f"{title!r}: the provenance has no date"


def test_the_readme_is_short_and_keeps_its_sections():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 150, "README.md: at most about 150 lines; details belong in docs/"
    sections = dict(re.findall(r"^## ([^\n]+)\n(.*?)(?=^## |\Z)", text, flags=re.MULTILINE | re.DOTALL))
    for title in ("Two commands", "Running the node", "Replaying a bag", "On a ROS 2 Jazzy machine", "How well it works",
                  "Documentation"):
        assert title in sections, f"README.md lost its section {title!r}"
    assert "make demo" in sections["Two commands"] and "make test" in sections["Two commands"]
    assert "ros2 launch" in sections["On a ROS 2 Jazzy machine"]
    results = sections["How well it works"]
    assert "|---" in results and re.search(r"`\.venv/bin/python bench/\w+\.py", results), \
        "the headline table and the command that produces it"
