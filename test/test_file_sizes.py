"""One concern per file: no source file of the package (line_odom/, line_odom_core/: .py, .pyi, .cpp, .hpp) runs over
600 lines unless the comment at its top says why, in a line "Over 600 lines: <why>"."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("line_odom", "line_odom_core")
SUFFIXES = {".py", ".pyi", ".cpp", ".hpp"}
MAX_LINES = 600
WHY = re.compile(r"\bOver 600 lines: \S")
# Files over the limit whose top does not say why yet; their owners decide whether to split them or to say why. The
# test fails when one of them is back under the limit or says why, so the list only shrinks.
PENDING = {
    "line_odom_core/cpp/registration/candidates.cpp",  # line-pair and plane-pair candidates
}


def source_files() -> list[Path]:
    return sorted(p for package in PACKAGES for p in (ROOT / package).rglob("*")
                  if p.suffix in SUFFIXES and p.is_file() and "__pycache__" not in p.parts)


def top_comment(path: Path, text: str) -> str:
    """The comment lines before the first line of code (C++), or the module docstring and the comment lines before it
    (Python)."""
    lines = text.splitlines()
    if path.suffix in {".py", ".pyi"}:
        leading = []
        for line in lines:
            if not line.startswith("#") and line.strip():
                break
            leading.append(line)
        try:
            docstring = ast.get_docstring(ast.parse(text)) or ""
        except SyntaxError:
            docstring = ""
        return "\n".join(leading) + "\n" + docstring
    leading = []
    for line in lines:
        stripped = line.strip()
        if stripped and not stripped.startswith(("//", "/*", "*")):
            break
        leading.append(line)
    return "\n".join(leading)


def too_long(path: Path) -> bool:
    text = path.read_text(encoding="utf-8", errors="replace")
    return len(text.splitlines()) > MAX_LINES and not WHY.search(top_comment(path, text))


def test_no_source_file_runs_over_600_lines_without_saying_why():
    files = source_files()
    assert len(files) > 50, "the package's sources were not found"
    long = sorted(str(p.relative_to(ROOT)) for p in files if too_long(p))
    assert sorted(set(long) - PENDING) == [], (
        f"over {MAX_LINES} lines without 'Over {MAX_LINES} lines: <why>' in the comment at the top: split them by "
        f"concern, or say why")
    settled = sorted(PENDING - set(long))
    assert settled == [], f"{settled}: under the limit or saying why now; take them off PENDING"


@pytest.mark.parametrize("suffix, comment", [(".cpp", "// Over 600 lines: {}\n"), (".py", '"""Over 600 lines: {}"""\n'),
                                             (".py", "#!/usr/bin/env python3\n# Over 600 lines: {}\n")])
def test_a_long_file_passes_only_when_its_top_says_why(tmp_path, suffix, comment):
    body = "x = 1\n" * (MAX_LINES + 1) if suffix == ".py" else "int x;\n" * (MAX_LINES + 1)
    path = tmp_path / f"long{suffix}"
    path.write_text(body)
    assert too_long(path)
    path.write_text(comment.format("one state machine; its parts share every member") + body)
    assert not too_long(path)
    path.write_text(body + comment.format("said at the bottom, not the top"))
    assert too_long(path)
    path.write_text("x = 1\n" * MAX_LINES)
    assert not too_long(path)
