"""The parameter tables of docs/NODE.md, generated from the settings' rows (the engine's C++ table through
line_odom_core.config_schema(), the node's line_odom.node_parameters.NODE_PARAMETERS).

    python -m line_odom.docs_tables            # rewrites the tables in docs/NODE.md
    python -m line_odom.docs_tables --check    # exit 1 when docs/NODE.md differs from the schema
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Iterable

from line_odom.node_parameters import NODE_PARAMETERS
from line_odom_core.config import ConfigEntry, config_schema

NODE_MD = Path(__file__).resolve().parents[1] / "docs" / "NODE.md"
BEGIN = "<!-- parameter tables: generated from the settings tables by python -m line_odom.docs_tables; do not edit -->"
END = "<!-- end of the generated parameter tables -->"


def default_text(value: Any) -> str:
    """A default as a parameter file writes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(default_text(v) for v in value) + "]"
    return str(value)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def table(entries: Iterable[ConfigEntry]) -> str:
    lines = ["| parameter | default | accepts | description |", "|---|---|---|---|"]
    for e in entries:
        lines.append(f"| `{e.name}` | `{default_text(e.default)}` | {_cell(e.expected)} | {_cell(e.description)} |")
    return "\n".join(lines)


def _runtime_sentence(entries: list[ConfigEntry]) -> str:
    live = [e.name for e in entries if e.runtime]
    if not live:
        return "None of them is applied while the node runs (each is declared read-only)."
    return "Applied while the node runs: " + ", ".join(f"`{n}`" for n in live) + "; the others are read-only."


def parameter_tables() -> str:
    """The generated block: the node's parameters, then the engine's settings."""
    node, engine = list(NODE_PARAMETERS), config_schema()
    return "\n\n".join([
        BEGIN,
        _runtime_sentence(node + engine),
        "The node's own parameters (`line_odom/node_parameters.py`):",
        table(node),
        "The engine's settings (`line_odom_core/cpp/odometry/engine_settings.cpp`), in the order the engine runs them:",
        table(engine),
        END,
    ])


def with_tables(document: str) -> str:
    """`document` with its generated block replaced by the current one."""
    start, end = document.find(BEGIN), document.find(END)
    if start < 0 or end < start:
        raise ValueError(f"{NODE_MD.name}: no generated block ({BEGIN!r} ... {END!r})")
    return document[:start] + parameter_tables() + document[end + len(END):]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m line_odom.docs_tables", description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 when docs/NODE.md differs from the schema")
    parser.add_argument("--doc", type=Path, default=NODE_MD, help="the document (default: docs/NODE.md)")
    args = parser.parse_args(argv)
    current = args.doc.read_text(encoding="utf-8")
    updated = with_tables(current)
    if args.check:
        if updated != current:
            print(f"{args.doc}: the parameter tables differ from the schema; run python -m line_odom.docs_tables",
                  file=sys.stderr)
            return 1
        return 0
    if updated != current:
        args.doc.write_text(updated, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
