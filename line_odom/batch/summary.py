"""The summary of a batch: one row per recording (status, seconds, metrics, the machine and commit that produced it),
mean / median / worst per metric, as summary.csv, summary.md and a bar chart summary.png."""
from __future__ import annotations

import csv
import io
import statistics
from pathlib import Path

from line_odom.batch.outputs import SUMMARY_CSV, SUMMARY_MD, SUMMARY_PLOT, atomic_write

# the metric keys in the order evaluation prints them; others follow alphabetically
METRIC_ORDER = ("frames", "frames_dropped", "frames_with_ground_truth", "path_length_m", "rpe_trans_mean_m",
                "rpe_trans_max_m", "rpe_rot_mean_deg", "rpe_rot_max_deg", "ate_rmse_m", "kitti_t_err_pct",
                "kitti_r_err_deg_per_m", "latency_mean_ms", "latency_p95_ms")
# "worst" of a metric is its largest value or its smallest; keys in neither set (path length, input counters) are
# properties of the recording and have none
LARGER_IS_BETTER = {"frames", "frames_with_ground_truth"}
SMALLER_IS_BETTER = {"frames_dropped", "rpe_trans_mean_m", "rpe_trans_max_m", "rpe_rot_mean_deg", "rpe_rot_max_deg",
                     "ate_rmse_m", "kitti_t_err_pct", "kitti_r_err_deg_per_m", "latency_mean_ms", "latency_p95_ms",
                     "seconds"}
PLOT_METRICS = (("rpe_trans_mean_m", "RPE translation mean [m]"), ("rpe_rot_mean_deg", "RPE rotation mean [deg]"),
                ("kitti_t_err_pct", "KITTI drift t_err [%]"))


def metric_keys(rows: list[dict]) -> list[str]:
    keys = {k for row in rows for k in row.get("metrics", {})}
    return [k for k in METRIC_ORDER if k in keys] + sorted(keys - set(METRIC_ORDER))


def aggregates(rows: list[dict]) -> dict[str, dict[str, float]]:
    """mean / median / worst of each metric (and seconds) over the recordings that have outputs."""
    good = [r for r in rows if r["status"] in ("ok", "skipped")]
    out = {}
    for key in metric_keys(good) + ["seconds"]:
        values = [float(r["seconds"] if key == "seconds" else r["metrics"][key]) for r in good
                  if (key == "seconds" or key in r["metrics"])]
        if not values:
            continue
        worst = min(values) if key in LARGER_IS_BETTER else max(values) if key in SMALLER_IS_BETTER else None
        out[key] = {"mean": statistics.fmean(values), "median": statistics.median(values), "worst": worst}
    return out


def _fmt(value) -> str:
    if value is None or value == "":
        return ""
    if isinstance(value, float):
        return "nan" if value != value else f"{value:.6g}"
    return str(value)



def summary_csv(rows: list[dict]) -> str:
    keys = metric_keys(rows)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["label", "input", "kind", "status", "seconds", "attempts", "error", "host", "commit"] + keys)
    for r in rows:
        w.writerow([r["label"], r["input"], r["kind"] or "", r["status"], _fmt(r.get("seconds")),
                    _fmt(r.get("attempts")), r.get("error", ""), r.get("host", ""), r.get("commit", "")]
                   + [_fmt(r["metrics"].get(k)) for k in keys])
    agg = aggregates(rows)
    for stat in ("mean", "median", "worst"):
        w.writerow([stat, "", "", "aggregate", _fmt(agg.get("seconds", {}).get(stat)), "", "", "", ""]
                   + [_fmt(agg[k][stat]) if k in agg else "" for k in keys])
    return buf.getvalue()


def summary_md(rows: list[dict], run_info: dict) -> str:
    keys = metric_keys(rows)
    failed = [r for r in rows if r["status"] == "failed"]
    counts = {s: sum(r["status"] == s for r in rows) for s in ("ok", "skipped", "failed")}
    m = run_info["machine"]
    lines = [
        "# line_odom batch",
        "",
        f"- inputs: `{run_info['inputs']}`; engine: {run_info['engine']}; frames: {run_info['frames'] or 'all'}",
        f"- machine: {m['host']} ({m['platform']}, {m['cpus']} cores, Python {m['python']}); line_odom "
        f"{m['line_odom']}, commit {m['commit']}; started {run_info['started']}, {run_info['wall_s']:.1f} s",
        f"- recordings: {len(rows)}; ran {counts['ok']}, skipped (complete) {counts['skipped']}, "
        f"failed {counts['failed']}",
        "",
        "| label | status | seconds | " + " | ".join(keys) + " |",
        "|---|---|---:|" + "---:|" * len(keys),
    ]
    for r in rows:
        lines.append(f"| {r['label']} | {r['status']} | {_fmt(r.get('seconds'))} | "
                     + " | ".join(_fmt(r["metrics"].get(k)) for k in keys) + " |")
    agg = aggregates(rows)
    lines += ["", "| aggregate | " + " | ".join(["seconds"] + keys) + " |", "|---|" + "---:|" * (len(keys) + 1)]
    for stat in ("mean", "median", "worst"):
        lines.append(f"| {stat} | " + " | ".join(_fmt(agg[k][stat]) if k in agg else ""
                                                for k in ["seconds"] + keys) + " |")
    lines += ["", f"failed: {len(failed)}"]
    for r in failed:
        lines.append(f"- {r['label']} (`{r['input']}`): {r['error']}")
    lines.append("")
    lines.append("Rows' machine and commit (a skipped row keeps those of the run that wrote it): see summary.csv.")
    return "\n".join(lines) + "\n"


def plot_summary(path: Path, rows: list[dict]) -> Path:
    """Bar chart of the per-recording RPE (and the KITTI drift where any recording has it); failed recordings
    and recordings without ground truth are marked."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    panels = [(k, t) for k, t in PLOT_METRICS if any(k in r["metrics"] for r in rows)] or [PLOT_METRICS[0]]
    labels = [r["label"] for r in rows]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels) + 2, 0.45 * len(rows) + 1.6), squeeze=False)
    y = list(range(len(rows)))
    for ax, (key, title) in zip(axes[0], panels):
        values = [r["metrics"].get(key, 0.0) for r in rows]
        colors = ["tab:red" if r["status"] == "failed" else "tab:blue" for r in rows]
        ax.barh(y, values, color=colors)
        top = max(values) if any(values) else 1.0
        for i, r in enumerate(rows):
            if r["status"] == "failed":
                ax.text(0, i, " failed", va="center", color="tab:red", fontsize=8)
            elif key not in r["metrics"]:
                ax.text(0, i, " n/a", va="center", color="gray", fontsize=8)
        ax.set_xlim(0, top * 1.15)
        ax.set_title(title, fontsize=10)
        ax.set_yticks(y)
        ax.set_yticklabels(labels if ax is axes[0][0] else [""] * len(rows), fontsize=8)
        ax.invert_yaxis()
        ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_write(path, buf.getvalue())
    return path


def write_summary(out_root: Path, rows: list[dict], run_info: dict) -> list[Path]:
    out_root.mkdir(parents=True, exist_ok=True)
    atomic_write(out_root / SUMMARY_CSV, summary_csv(rows))
    atomic_write(out_root / SUMMARY_MD, summary_md(rows, run_info))
    plot_summary(out_root / SUMMARY_PLOT, rows)
    return [out_root / SUMMARY_CSV, out_root / SUMMARY_MD, out_root / SUMMARY_PLOT]
