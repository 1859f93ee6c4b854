"""The type stubs say what the engine's modules export: line_odom_core/_core.pyi and line_odom_core/_testing.pyi list
exactly the live modules' names, each function and method with the parameters pybind11 reports (names, order,
keyword-only, defaults), and the stats keys documented on FrameResult are those of a frame the engine registered.
The production module carries none of the testing module's hooks."""
from __future__ import annotations

import ast
import math
import re
from pathlib import Path
from types import ModuleType

import pytest

import line_odom_core
from line_odom_core import _core, _testing

STUBS = Path(line_odom_core.__file__).resolve().parent
MODULES = {"_core": _core, "_testing": _testing}


# ---- the stub, read with ast ----

def _stub_params(fn: ast.FunctionDef, method: bool) -> list[tuple[str, bool, bool, object]]:
    """(name, keyword_only, has_default, default or Ellipsis when not a literal) of a stub's def."""
    a = fn.args
    positional = [*a.posonlyargs, *a.args]
    defaults = [None] * (len(positional) - len(a.defaults)) + list(a.defaults)
    params = [(p.arg, False, d) for p, d in zip(positional, defaults)]
    params += [(p.arg, True, d) for p, d in zip(a.kwonlyargs, a.kw_defaults)]
    if method:
        params = params[1:]  # self

    def value(node):
        try:
            return ast.literal_eval(node)
        except ValueError:
            return Ellipsis

    return [(name, kw, d is not None, Ellipsis if d is None else value(d)) for name, kw, d in params]


def _stub_members(body: list[ast.stmt], method: bool) -> dict[str, tuple[str, object]]:
    """name -> ("function", params) | ("property", None) | ("attribute", None) | ("class", members)."""
    out: dict[str, tuple[str, object]] = {}
    for node in body:
        if isinstance(node, ast.FunctionDef):
            is_property = any(isinstance(d, ast.Name) and d.id == "property" for d in node.decorator_list)
            out[node.name] = ("property", None) if is_property else ("function", _stub_params(node, method))
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            out[node.target.id] = ("attribute", None)
        elif isinstance(node, ast.ClassDef):
            out[node.name] = ("class", (_stub_members(node.body, True), ast.get_docstring(node) or ""))
    return out


def stub_of(name: str) -> dict[str, tuple[str, object]]:
    return _stub_members(ast.parse((STUBS / f"{name}.pyi").read_text(encoding="utf-8")).body, False)


# ---- the live module, read from pybind11's signatures ----

def _split_top_level(text: str) -> list[str]:
    """Splits at commas outside brackets and quotes."""
    parts, depth, quote, start = [], 0, "", 0
    for i, ch in enumerate(text):
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    if text[start:].strip():
        parts.append(text[start:])
    return [p.strip() for p in parts]


def _default_value(text: str):
    special = {"inf": math.inf, "-inf": -math.inf}
    if text in special:
        return special[text]
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return Ellipsis


def live_params(obj, method: bool) -> list[tuple[str, bool, bool, object]]:
    """The parameters of a pybind11 function from the signature line heading its docstring."""
    first = (obj.__doc__ or "").splitlines()[0] if obj.__doc__ else ""
    assert not first.startswith("Overloaded"), f"{obj.__name__}: overloads are not described by the stub check"
    match = re.match(r"^\w+\((.*)\) -> .*$", first)
    assert match, f"{obj!r}: no pybind11 signature in its docstring: {first!r}"
    params, keyword_only = [], False
    for part in _split_top_level(match.group(1)):
        if part == "*":
            keyword_only = True
            continue
        if part == "/":
            continue
        name, _, rest = part.partition(":")
        _, eq, default = rest.rpartition(" = ")
        params.append((name.strip(), keyword_only, bool(eq), _default_value(default.strip()) if eq else Ellipsis))
    return params[1:] if method else params


def _public(names) -> list[str]:
    return sorted(n for n in names if n == "__version__" or not n.startswith("_"))


def live_members(obj, method: bool) -> dict[str, tuple[str, object]]:
    out: dict[str, tuple[str, object]] = {}
    names = _public(vars(obj)) if isinstance(obj, type) else _public(dir(obj))
    for name in names:
        value = vars(obj)[name] if isinstance(obj, type) else getattr(obj, name)
        if isinstance(value, property):
            out[name] = ("property", None)
        elif isinstance(value, type):
            out[name] = ("class", (live_members(value, True), value.__doc__ or ""))
        elif callable(value):
            out[name] = ("function", live_params(value, method))
        else:
            out[name] = ("attribute", None)
    return out


def _pybind_init(cls: type):
    init = vars(cls).get("__init__")
    doc = getattr(init, "__doc__", "") or ""
    return init if doc.startswith("__init__(") else None


def compare(stub: dict, live: dict, where: str) -> list[str]:
    problems = []
    for name in sorted(set(stub) | set(live)):
        if name not in live:
            problems.append(f"{where}{name}: in the stub, not in the module")
            continue
        if name not in stub:
            problems.append(f"{where}{name}: in the module, not in the stub")
            continue
        (s_kind, s_info), (l_kind, l_info) = stub[name], live[name]
        if s_kind == "attribute" and l_kind == "property":
            continue  # def_readonly: an attribute of the instances
        if s_kind != l_kind:
            problems.append(f"{where}{name}: a {s_kind} in the stub, a {l_kind} in the module")
        elif s_kind == "function":
            problems += _compare_params(s_info, l_info, f"{where}{name}")
        elif s_kind == "class":
            problems += compare(s_info[0], l_info[0], f"{where}{name}.")
    return problems


def _compare_params(stub: list, live: list, where: str) -> list[str]:
    if [p[:3] for p in stub] != [p[:3] for p in live]:
        return [f"{where}: parameters (name, keyword-only, has default) {[p[:3] for p in stub]} in the stub, "
                f"{[p[:3] for p in live]} in the module"]
    problems = []
    for (name, _, has_default, s_default), (_, _, _, l_default) in zip(stub, live):
        if has_default and s_default is not Ellipsis and l_default is not Ellipsis and s_default != l_default:
            problems.append(f"{where}: default of {name} is {s_default!r} in the stub, {l_default!r} in the module")
    return problems


def _live_with_init(module: ModuleType) -> dict:
    live = live_members(module, False)
    for name, (kind, info) in live.items():
        if kind == "class":
            init = _pybind_init(getattr(module, name))
            if init is not None:
                info[0]["__init__"] = ("function", live_params(init, True))
    return live


# ---- the tests ----

@pytest.mark.parametrize("name", sorted(MODULES))
def test_the_stub_lists_exactly_what_the_module_exports(name):
    problems = compare(stub_of(name), _live_with_init(MODULES[name]), f"{name}.")
    assert problems == [], f"line_odom_core/{name}.pyi differs from the module:\n" + "\n".join(problems)


def test_the_check_sees_a_drift():
    live = _live_with_init(_core)
    stub = stub_of("_core")
    renamed = {**stub, "solve_3l1p_renamed": stub["solve_3l1p"]}
    del renamed["solve_3l1p"]
    assert len(compare(renamed, live, "")) == 2
    name, kw, has_default, _ = stub["solve_7l"][1][-1]
    moved = {**stub, "solve_7l": ("function", [*stub["solve_7l"][1][:-1], (name, kw, has_default, 1.0)])}
    assert compare(moved, live, "") == ["solve_7l: default of max_residual is 1.0 in the stub, inf in the module"]
    odometry = stub["Odometry"][1][0]
    fewer = {**stub, "Odometry": ("class", ({k: v for k, v in odometry.items() if k != "frames"}, ""))}
    assert compare(fewer, live, "") == ["Odometry.frames: in the module, not in the stub"]


def test_the_production_module_carries_no_test_or_benchmark_hook():
    hooks = set(_public(dir(_testing)))
    assert hooks, "the testing module exports nothing"
    assert hooks.isdisjoint(dir(_core)), sorted(hooks & set(dir(_core)))
    private = [n for n in dir(_core) if n.startswith("_") and not n.startswith("__") and not n.startswith("_pybind11")]
    assert private == [], f"_core exports private (test) names: {private}"
    assert not any("benchmark" in n or n.startswith("ransac_") for n in dir(_core))


def test_the_node_does_not_load_the_testing_module():
    import subprocess
    import sys

    code = ("import sys, line_odom.node, line_odom.lifecycle_node; "
            "print(' '.join(m for m in sys.modules if m.startswith('line_odom_core.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    loaded = out.stdout.split()
    assert "line_odom_core._core" in loaded and "line_odom_core._testing" not in loaded, loaded


# ---- FrameResult.stats, as documented in the stub's FrameResult docstring ----

def documented_stats_keys(doc: str) -> tuple[set[str], set[str]]:
    """The keys of the sections 'stats keys:' and 'stats["ms"] keys:': one entry a line, indented by two, its names
    before the first ':' (several separated by ',')."""
    sections: dict[str, set[str]] = {}
    current = None
    for line in doc.splitlines():
        if re.match(r"^stats keys:$", line.strip()) or line.strip() == 'stats["ms"] keys:':
            current = sections.setdefault(line.strip(), set())
            continue
        if current is None:
            continue
        if not line.strip():
            current = None
            continue
        entry = re.match(r"^  (\w+(?:, \w+)*)(?::|\s{2,}|$)", line)
        if entry:
            current.update(n.strip() for n in entry.group(1).split(","))
    return sections.get("stats keys:", set()), sections.get('stats["ms"] keys:', set())


def a_registered_frame():
    from line_odom.sim.runner import make

    sim = make("room", frames=2)
    engine = _core.Odometry(line_odom_core.load_config("tum_kinect", {"downsample": 2}).as_dict())
    results = [engine.register_depth(frame.data, sim.sensor.K, frame.stamp) for frame in sim]
    assert results[-1].stats["registered"]
    return results[-1]


def test_the_documented_stats_keys_are_those_of_a_registered_frame():
    result = a_registered_frame()
    assert isinstance(result, _core.FrameResult)
    keys, ms_keys = documented_stats_keys(stub_of("_core")["FrameResult"][1][1])
    assert keys, "no 'stats keys:' section in the FrameResult docstring of _core.pyi"
    stats = result.stats
    assert (sorted(keys - set(stats)), sorted(set(stats) - keys)) == ([], []), \
        "FrameResult stats keys (documented but absent, present but undocumented)"
    assert (sorted(ms_keys - set(stats["ms"])), sorted(set(stats["ms"]) - ms_keys)) == ([], []), \
        'FrameResult stats["ms"] keys (documented but absent, present but undocumented)'


def test_the_stats_key_reader_reads_names_lists_and_sections():
    doc = ('One frame.\n\nstats keys:\n  solver: str   the winner\n  h_lines, v_lines: int  lines\n'
           '      continuation: not a key\n  ms: dict    per stage\n\nstats["ms"] keys:\n  organize    the organize\n'
           '  total       all\n')
    assert documented_stats_keys(doc) == ({"solver", "h_lines", "v_lines", "ms"}, {"organize", "total"})
