"""Solver benchmark (docs/DESIGN.md §6): C++ timing loop over seeded noise-free instances, no Python per call.

Prints per solver: median and 90th percentile µs per call (each pass over the instances is timed in chunks of
consecutive calls, tens of µs long, so that most chunks run unpreempted on a loaded machine; every chunk is one
sample), solutions per call, found-ground-truth rate (some solution within 1e-6, max abs 4x4 entry), next to the
paper's timings and the authors' later C++.

    .venv/bin/python bench/solvers.py [--instances 20000] [--repetitions 7] [--seed 0] [--markdown]
"""
import argparse
import datetime
import glob
import os
import platform
import subprocess
import sys
import sysconfig
import tempfile

from line_odom_core import _core, _testing

# paper (Ranade et al. 2019, §7) and the authors' later public C++ (MIT, 2020) timed on this machine at -O3
PAPER_US = {"1l2p": 0.64, "3l1p": 4.9, "7l": 22000.0}
AUTHORS_CPP = {"1l2p": "0.55 µs", "3l1p": "3.2 µs, 89.5 % within 1e-6", "7l": "-"}
TARGET_US = {"1l2p": 0.3, "3l1p": 2.0, "7l": 500.0}


def run(args):
    rows = []
    plan = [("1l2p", "", args.instances), ("3l1p", "", args.instances),
            ("7l", "gauss_newton", args.instances_7l),
            ("7l", "alternating_projection", args.instances_ap)]
    for solver, method, n in plan:
        kw = {"method": method} if method else {}
        if method == "alternating_projection":
            kw["max_iterations"] = args.ap_max_iterations
        reps = args.repetitions if method != "alternating_projection" else max(1, min(args.repetitions, 3))
        r = _testing.benchmark_solver(solver, n, reps, args.seed, **kw)
        rows.append(r)
    return rows


ALLOCATION_SYMBOLS = ("malloc", "calloc", "realloc", "free", "operator new", "operator delete")


def allocation_symbols():
    """Compiles each solver translation unit alone (-O3, as the module) and lists the allocation functions it
    references: none referenced = no heap allocation possible in a solver call (all Eigen code is inlined)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cpp = os.path.join(root, "line_odom_core", "cpp")
    eigen = next((d for d in ["/usr/include/eigen3", "/usr/local/include/eigen3"] if os.path.isdir(d)), None)
    cxx = sysconfig.get_config_var("CXX") or "g++"
    if eigen is None:
        return {"(Eigen headers not found)": []}
    found = {}
    with tempfile.TemporaryDirectory() as tmp:
        for src in sorted(glob.glob(os.path.join(cpp, "solvers", "*.cpp"))):
            obj = os.path.join(tmp, os.path.basename(src) + ".o")
            subprocess.run([cxx.split()[0], "-std=c++17", "-O3", "-DNDEBUG", "-I", cpp, "-I", eigen, "-c", src, "-o", obj],
                           check=True)
            undefined = subprocess.run(["nm", "-C", "--undefined-only", obj], check=True, capture_output=True,
                                       text=True).stdout.split("\n")
            found[os.path.basename(src)] = sorted({line.split(" U ")[-1].strip() for line in undefined
                                                   if any(s in line for s in ALLOCATION_SYMBOLS)})
    return found


def format_table(rows, markdown):
    head = ["solver", "instances", "median µs/call", "p90 µs/call", "mean µs/call", "solutions/call", "found GT (1e-6)",
            "p99 error", "iterations", "target µs", "paper µs", "authors' C++"]
    lines = []
    for r in rows:
        name = r["solver"].upper() + (f" {r['method']}" if r["method"] else "")
        lines.append([name, str(r["instances"]), f"{r['median_us']:.3f}", f"{r['p90_us']:.3f}", f"{r['mean_us']:.3f}",
                      f"{r['solutions_per_call']:.3f}", f"{100 * r['found_rate']:.2f} %", f"{r['p99_error']:.1e}",
                      f"{r['mean_iterations']:.1f}" if r["solver"] == "7l" else "-",
                      f"{TARGET_US[r['solver']]:g}" if r["method"] != "alternating_projection" else "-",
                      f"{PAPER_US[r['solver']]:g}", AUTHORS_CPP[r["solver"]]])
    if markdown:
        out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        out += ["| " + " | ".join(line) + " |" for line in lines]
        return "\n".join(out)
    widths = [max(len(h), *(len(line[i]) for line in lines)) for i, h in enumerate(head)]
    fmt = "  ".join("{:<%d}" % w for w in widths)
    return "\n".join([fmt.format(*head), fmt.format(*("-" * w for w in widths))] + [fmt.format(*l) for l in lines])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--instances", type=int, default=20000, help="instances for 1L2P and 3L1P")
    parser.add_argument("--instances-7l", type=int, default=2000, help="instances for 7L Gauss-Newton")
    parser.add_argument("--instances-ap", type=int, default=100, help="instances for 7L alternating projection")
    parser.add_argument("--ap-max-iterations", type=int, default=30000)
    parser.add_argument("--repetitions", type=int, default=7)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--markdown", action="store_true")
    parser.add_argument("--no-allocation-check", action="store_true",
                        help="skip compiling the solver sources to list the allocation functions they reference")
    args = parser.parse_args()
    rows = run(args)
    info = _core.build_info()
    print(f"# solver benchmark {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, {info['compiler']} {info['flags']}, "
          f"seed {args.seed}")
    print("# 7L starts from the truth moved by up to 5 deg and 0.5 m; rotations uniform; scene 10 m; t up to 2 m")
    print(format_table(rows, args.markdown))
    if not args.no_allocation_check:
        try:
            found = allocation_symbols()
        except (OSError, subprocess.CalledProcessError) as exc:
            print(f"# allocation check skipped: {exc}", file=sys.stderr)
        else:
            for name, symbols in found.items():
                print(f"# {name}: references {', '.join(symbols) if symbols else 'no allocation function'}")


if __name__ == "__main__":
    main()
