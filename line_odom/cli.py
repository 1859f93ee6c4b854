"""The `line_odom` command line: kitti2bag, tum2bag, replay, eval, demo, batch.

Every failure is one line on stderr (``line_odom: error: ...``) and a non-zero return code, never a traceback.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _add_bag_output_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3", help="rosbag2 storage (default sqlite3)")
    p.add_argument("--frames", type=_positive_int, default=None, help="convert only the first N frames")
    p.add_argument("--overwrite", action="store_true", help="replace OUT_BAG if it exists")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _replay_formats() -> tuple[str, ...]:
    from line_odom.readers import FORMATS

    return FORMATS


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="line_odom",
        description="Sparse-scan LiDAR and depth odometry from line-intersection constraints: dataset "
                    "conversion, bag replay through the node, evaluation, and a self-contained demo.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("kitti2bag", help="KITTI odometry sequence -> rosbag2 (PointCloud2, ground truth, calibration)")
    p.add_argument("seq_dir", metavar="SEQ_DIR", help="sequence directory with velodyne/, times.txt, calib.txt "
                                                      "(and optionally poses_gt.txt / poses.txt)")
    p.add_argument("out_bag", metavar="OUT_BAG", help="output bag directory (must not exist)")
    _add_bag_output_args(p)

    p = sub.add_parser("tum2bag", help="TUM RGB-D sequence -> rosbag2 (16UC1 depth Image + CameraInfo, ground truth)")
    p.add_argument("tum_dir", metavar="TUM_DIR", help="sequence directory with depth.txt, depth/ (and "
                                                      "optionally groundtruth.txt)")
    p.add_argument("out_bag", metavar="OUT_BAG", help="output bag directory (must not exist)")
    p.add_argument("--camera", default=None, help="intrinsics: fr1, fr2, fr3, ros_default or 'fx,fy,cx,cy' "
                                                  "(default: from the directory name, else fr1)")
    _add_bag_output_args(p)

    p = sub.add_parser("replay", help="run a recording (bag, pcap, osf, dataset folder, scans) through the odometry "
                                      "node and evaluate it")
    p.add_argument("bag", metavar="PATH", help="a rosbag2 (sqlite3 or mcap), ROS 1 .bag, Velodyne or Ouster .pcap, "
                                               "Ouster .osf, KITTI odometry / raw folder, TUM RGB-D folder or "
                                               "folder of .bin / .pcd / .ply scans (docs/TOOLS.md)")
    p.add_argument("--format", default=None, choices=_replay_formats(),
                   help="the recording's format (default: guessed from PATH)")
    p.add_argument("--meta", metavar="JSON", default=None,
                   help="an Ouster pcap's sensor metadata (default: the json beside it whose name starts the pcap's)")
    p.add_argument("--ground-truth", metavar="FILE", default=None, dest="ground_truth",
                   help="a TUM or KITTI trajectory file (KITTI: one pose a frame) instead of the recording's own")
    p.add_argument("--plot-features", metavar="N", type=int, nargs="?", const=0, default=None, dest="plot_features",
                   help="also draw frame N's kept points and the H/V lines it was registered with (the node's "
                        "~/scan and ~/lines), top view, to DIR/features.png (default 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory for trajectories, metrics and plot")
    p.add_argument("--params", metavar="YAML", default=None, help="ROS 2 parameter file (or preset name) for the node "
                                                              "(default: the preset the recording suggests)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", dest="overrides",
                   help="override one parameter (engine or node), e.g. --set downsample=6; repeatable")
    p.add_argument("--realtime", action="store_true",
                   help="run the node in its own process and publish over DDS at bag rate with /clock "
                        "(default: in-process, as fast as possible, every frame)")
    p.add_argument("--rate", type=float, default=1.0, metavar="FACTOR",
                   help="with --realtime: play at FACTOR x the bag's pace (e.g. 0.5 = half speed)")
    p.add_argument("--out-bag", metavar="BAG", default=None, help="also write the node's Odometry and Path to this bag")
    p.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3", help="storage of --out-bag")
    p.add_argument("--topic", default=None, help="input topic (default: the bag's only PointCloud2 or Image topic)")
    p.add_argument("--frames", type=_positive_int, default=None, help="replay only the first N frames")
    p.add_argument("--guess-topic", default=None, metavar="TOPIC",
                   help="a nav_msgs/Odometry topic of the bag (wheel odometry) as the node's motion guess "
                        "(guess.enabled)")
    p.add_argument("--imu-topic", default=None, metavar="TOPIC",
                   help="a sensor_msgs/Imu topic of the bag whose gyro rates turn the node's prediction "
                        "(imu.enabled)")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no table")

    p = sub.add_parser("batch", help="replay every recording of a folder or manifest (local processes or a Dask "
                                     "cluster) and summarize the metrics")
    p.add_argument("inputs", metavar="INPUTS", help="a folder (every recording replay reads, searched recursively) "
                                                    "or a manifest (.yaml/.csv: path, label, params, set)")
    p.add_argument("--out", required=True, metavar="DIR", help="outputs: DIR/<label>/ per recording, DIR/summary.*")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                       help="local worker processes (default: the cores)")
    where.add_argument("--cluster", default=None, metavar="ADDRESS",
                       help="run on this existing Dask scheduler (tcp://host:8786, or its scheduler file .json)")
    p.add_argument("--params", metavar="YAML", default=None, help="parameter file for recordings without their own")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", dest="overrides",
                   help="override one parameter for every recording (a manifest entry's own set wins); repeatable")
    p.add_argument("--frames", type=_positive_int, default=None, metavar="N",
                   help="replay only the first N frames of each")
    p.add_argument("--force", action="store_true", help="replay recordings whose outputs are complete too")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no report")

    p = sub.add_parser("eval", help="metrics of an estimated trajectory against ground truth (TUM or KITTI files)")
    p.add_argument("est", metavar="EST", help="estimated trajectory (TUM: t x y z qx qy qz qw, or KITTI: 12 numbers)")
    p.add_argument("gt", metavar="GT", help="ground-truth trajectory (TUM or KITTI)")
    p.add_argument("--json", metavar="FILE", default=None, help="write the metrics to this JSON file")
    p.add_argument("--plot", metavar="PNG", default=None, help="write the trajectory plot to this file")

    p = sub.add_parser("demo", help="simulate a LiDAR street drive and a depth-camera room, replay both through "
                                    "the node, print the metrics and write the plots (no download)")
    p.add_argument("--out", default="demo_out", metavar="DIR", help="output directory (default ./demo_out)")
    p.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3", help="storage of the demo bags")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


# --------------------------------------------------------------------------------------------- commands


def _progress(label: str, quiet: bool):
    from line_odom.progress import ProgressBar

    return ProgressBar(label, enabled=False if quiet else None)


def cmd_kitti2bag(args) -> int:
    from line_odom import bags

    with _progress("kitti2bag", args.quiet) as bar:
        n = bags.kitti_to_bag(args.seq_dir, args.out_bag, storage=args.storage, frames=args.frames,
                              overwrite=args.overwrite, progress=bar)
    print(f"wrote {n} scans to {args.out_bag} ({args.storage}): {bags.KITTI_POINTS_TOPIC}, "
          f"{bags.GROUND_TRUTH_TOPIC}, {bags.TF_STATIC_TOPIC}")
    return 0


def cmd_tum2bag(args) -> int:
    from line_odom import bags

    with _progress("tum2bag", args.quiet) as bar:
        n = bags.tum_to_bag(args.tum_dir, args.out_bag, storage=args.storage, frames=args.frames,
                            camera=args.camera, overwrite=args.overwrite, progress=bar)
    print(f"wrote {n} depth frames to {args.out_bag} ({args.storage}): {bags.TUM_DEPTH_TOPIC}, "
          f"{bags.TUM_INFO_TOPIC}, {bags.GROUND_TRUTH_TOPIC}")
    return 0


def cmd_eval(args) -> int:
    from line_odom import evaluation

    est = evaluation.read_trajectory(args.est)
    gt = evaluation.read_trajectory(args.gt)
    values = evaluation.compute_metrics(est, gt)
    print(evaluation.format_table(values, f"{args.est} vs {args.gt}"))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(values, indent=2) + "\n")
    if args.plot:
        from line_odom.plot import plot_trajectory

        plot_trajectory(args.plot, est, gt, title=Path(args.est).name)
    return 0


def parse_overrides(items: list[str]) -> dict:
    """["downsample=6", "ransac.solver=7L"] -> {"downsample": 6, "ransac.solver": "7L"} (values read as YAML)."""
    import yaml

    from line_odom_core.config import yaml_load

    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--set: expected NAME=VALUE, got {item!r}")
        try:
            out[name.strip()] = yaml_load(text)
        except yaml.YAMLError:
            raise ValueError(f"--set {name}: cannot read the value {text!r}") from None
    return out


def cmd_replay(args) -> int:
    from line_odom import evaluation, replay

    result = replay.replay(args.bag, args.out, format=args.format, meta=args.meta, ground_truth=args.ground_truth,
                           plot_features=args.plot_features, params=args.params,
                           overrides=parse_overrides(args.overrides), realtime=args.realtime, rate=args.rate,
                           out_bag=args.out_bag, out_bag_storage=args.storage, topic=args.topic,
                           frames=args.frames, progress=not args.quiet, guess_topic=args.guess_topic,
                           imu_topic=args.imu_topic)
    if not args.quiet:
        info = result.input
        print(f"input: {info.get('format')}, preset {info.get('preset')} ({info.get('sensor')}); ground truth: "
              f"{info.get('ground_truth') or 'none'}" + "".join(f"; {note}" for note in info.get("notes", [])))
        print(evaluation.format_table(result.metrics, f"replay {args.bag}"))
        print(f"wrote {', '.join(str(p) for p in result.files)}")
    return 0


def cmd_batch(args) -> int:
    from line_odom import batch

    result = batch.run_batch(args.inputs, args.out, workers=args.workers, cluster=args.cluster, params=args.params,
                             overrides=parse_overrides(args.overrides), frames=args.frames, force=args.force,
                             progress=not args.quiet)
    counts = {s: sum(r["status"] == s for r in result.rows) for s in ("ok", "skipped", "failed")}
    if not args.quiet:
        print(f"{len(result.rows)} recordings: {counts['ok']} replayed, {counts['skipped']} skipped (complete), "
              f"{counts['failed']} failed; wrote {', '.join(str(p) for p in result.files)}")
    if result.failed:
        raise RuntimeError(f"{len(result.failed)} of {len(result.rows)} recordings failed "
                           f"({', '.join(r['label'] for r in result.failed)}; errors in {result.files[1]})")
    return 0


def cmd_demo(args) -> int:
    from line_odom import demo

    demo.run_demo(args.out, storage=args.storage, progress=not args.quiet)
    return 0


COMMANDS = {"kitti2bag": cmd_kitti2bag, "tum2bag": cmd_tum2bag, "replay": cmd_replay, "eval": cmd_eval,
            "demo": cmd_demo, "batch": cmd_batch}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse has printed the usage and its one-line error
        return int(exc.code) if isinstance(exc.code, int) else EXIT_USAGE
    try:
        return COMMANDS[args.command](args)
    except KeyboardInterrupt:
        print("line_odom: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:  # every failure is one clear line, never a traceback
        message = str(exc) or type(exc).__name__
        if isinstance(exc, (FileNotFoundError, FileExistsError, PermissionError)) and exc.filename and \
                str(exc.filename) not in message:
            message = f"{exc.filename}: {message}"
        if not isinstance(exc, (ValueError, OSError, RuntimeError, KeyError)):
            message = f"{type(exc).__name__}: {message}"
        print(f"line_odom {args.command}: error: {message.splitlines()[0] if message else ''}", file=sys.stderr)
        return EXIT_ERROR


if __name__ == "__main__":
    raise SystemExit(main())
