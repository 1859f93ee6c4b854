#!/usr/bin/env python3
"""Frame-to-frame accuracy of line_odom next to KISS-ICP on the same frames, in one run.

    .venv/bin/python bench/accuracy.py                  # KITTI 00/04/07 at 1, 1/36, 1/64; TUM fr1/xyz at 1, 1/100
    .venv/bin/python bench/accuracy.py --only kitti --kitti-levels 6
    .venv/bin/python bench/accuracy.py --sim            # + the simulated 1 km street drive (KITTI devkit metric)
    .venv/bin/python bench/accuracy.py --only sim --sim-sensor vlp16   # the same street with a 16-beam LiDAR
    .venv/bin/python bench/accuracy.py --only sim --sim-distortion     # sweeps cast while moving: deskew on / off
    .venv/bin/python bench/accuracy.py --only sim --sim-distortion --sim-stamp end --no-kiss   # stamped at the sweep's end
    .venv/bin/python bench/accuracy.py --only sim --sim-distortion --sim-speed-swing 0.5 4   # speed 5-15 m/s every 4 s
    .venv/bin/python bench/accuracy.py --seeds 8        # + line_odom's spread over RANSAC seeds 0-7
    .venv/bin/python bench/accuracy.py --only kitti --kitti-levels --kitti-beams 16 32   # KITTI with 16 / 32 lasers
    .venv/bin/python bench/accuracy.py --only kitti --kitti-stride 2   # every 2nd scan: each scan moves twice as far
    .venv/bin/python bench/accuracy.py --only kitti --kitti-backwards  # each run backwards: stops become starts
    .venv/bin/python bench/accuracy.py --only kitti --kitti-start 3    # each run from scan 3 (from 0): mid-drive
    .venv/bin/python bench/accuracy.py --only kitti --kitti-mount 10 15 0   # a sensor tilted 10 deg in roll, 15 in pitch
    .venv/bin/python bench/accuracy.py --only kitti --kitti-view 180   # a sensor seeing only the half ahead of it
    .venv/bin/python bench/accuracy.py --only kitti --kitti-levels --kitti-beams 16 32 --kitti-firing-rings
    .venv/bin/python bench/accuracy.py --only kitti --kitti-stamp-jitter 5   # stamps off by up to 5 ms either way

Prints mean/max RPE (translation m, rotation deg) per sequence and resolution for both methods, the paper's
figures where it has them, and whether each goal is met; then, per row with KISS-ICP, the paired
difference of the two methods' per-frame errors with a 95 % bootstrap interval (line_odom.metrics.paired_difference):
whether the row's frames tell which method's mean is lower (nine pairs per KITTI row: often they do not). The "16b"
and "32b" rows keep every 4th / 2nd of KITTI's 64 lasers with all their azimuth steps (a real scan as a 16- or 32-beam
LiDAR samples it, through the vlp16 preset). KISS-ICP and GenZ-ICP (benchmark-only dependencies:
`.venv/bin/pip install kiss-icp genz-icp`) get exactly the points line_odom keeps after organizing and downsampling,
deskew off, cold start, one thread each as line_odom's presets. On KITTI 00 and 08, whose ground truth disagrees with their scans (the data's README,
bench/gt_consistency.py), translation is judged against a dense registration of the same scans (every point,
point-to-plane, started at the ground truth) and rotation against the ground truth. `--markdown FILE` writes the
summary as the markdown table of docs/RESULTS.md, "Accuracy", with its provenance line.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))

import line_odom_core  # noqa: E402
from line_odom.datasets import kitti_sequence, tum_sequence  # noqa: E402
from line_odom.metrics import frame_motions, paired_difference, relative_pose_errors  # noqa: E402

KITTI_LEVELS = {1: "full", 6: "1/36", 8: "1/64"}
TUM_LEVELS = {1: "full", 10: "1/100"}
# s added to the depth stamps where the ground truth is read: fr1's depth images are stamped ~40 ms after the scene the
# motion capture saw them in (both methods' rotation error is least there; docs/RESULTS.md, "Accuracy")
TUM_CLOCK_OFFSETS = (0.0, -0.02, -0.03, -0.04, -0.05, -0.06)
# The paper's own mean RPE (m, deg): KITTI 07 at full resolution, TUM fr1/xyz at 1/100 (Tables 1, 4; Fig. 1).
PAPER = {("kitti", "07", 1): (0.0176, 0.0838), ("tum", "fr1/xyz", 10): (0.00505, 0.52)}


def kiss_available() -> bool:
    try:
        import kiss_icp  # noqa: F401
    except ImportError:
        return False
    return True


KISS_HINT = "KISS-ICP is not installed: `.venv/bin/pip install kiss-icp` (benchmark-only dependency)"


def overrides_and_kiss(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[dict, bool]:
    """The engine overrides of --set (a usage error when one is malformed) and whether KISS-ICP runs (not
    --no-kiss, and installed; else the install hint is printed)."""
    from line_odom.cli import parse_overrides

    try:
        overrides = parse_overrides(args.set)
    except ValueError as err:
        parser.error(str(err))
    kiss = not args.no_kiss and kiss_available()
    if not args.no_kiss and not kiss:
        print(KISS_HINT)
    return overrides, kiss


def kiss_odometry(max_range: float, threads: int = 1, deskew: bool = False):
    from kiss_icp.config import load_config
    from kiss_icp.kiss_icp import KissICP

    config = load_config(None)
    config.data.deskew = deskew
    config.data.max_range = max_range
    config.mapping.voxel_size = max_range / 100.0
    config.registration.max_num_threads = threads
    return KissICP(config)


@dataclasses.dataclass
class Run:
    poses: np.ndarray
    ms: list[float]
    stats: list[dict]


@dataclasses.dataclass
class Row:
    dataset: str
    sequence: str
    level: int
    frames: int
    lo: tuple[float, float, float, float]   # mean t, max t, mean r, max r
    kiss: tuple[float, float, float, float] | None
    lo_ms: float
    kiss_ms: float | None
    degenerate: int
    beams: int = 0  # KITTI kept to this many of the HDL-64E's lasers (0: all of them)
    lo_frames: tuple[np.ndarray, np.ndarray] | None = None    # per frame pair: t (m), r (deg)
    kiss_frames: tuple[np.ndarray, np.ndarray] | None = None
    # TUM: (offset s, line_odom mean t, r, KISS-ICP mean t, r or None) with the ground truth at the stamps + offset
    clock: list[tuple] | None = None
    genz: tuple[float, float, float, float] | None = None  # GenZ-ICP on the same points
    genz_ms: float | None = None
    motion: float = 0.0   # mean motion per frame (m) of the poses judged against
    flagged: int = 0      # frames flagged: degenerate or not registered
    gross: int = -1       # gross frames not flagged (-1: not counted)
    dense_reference: bool = False  # translation judged against the dense registration (ground truth disagrees)
    kiss_reference: bool = False   # judged against KISS-ICP's own full-resolution poses (the stop-and-go drive)
    source: str = ""               # what open_run was given: a shared run's name or a directory
    playback: "Playback" = None    # how a KITTI run was played (None: as recorded)


def frame_errors(poses: np.ndarray, gt: np.ndarray, valid: np.ndarray | None = None):
    t, r = relative_pose_errors(poses, gt)
    if valid is not None:
        keep = valid[:-1] & valid[1:]
        t, r = t[keep], r[keep]
    return t, r


def summary(errors: tuple[np.ndarray, np.ndarray]):
    t, r = errors
    return float(t.mean()), float(t.max()), float(r.mean()), float(r.max())


def beams_config(beams: int, overrides: dict):
    """The vlp16 preset for KITTI kept to `beams` of its 64 lasers: `beams` rows between the HDL-64E's elevations."""
    return line_odom_core.load_config("vlp16", {"sensor.model": "uniform", "sensor.rows": beams,
                                                "sensor.max_elevation_deg": 2.0, "sensor.min_elevation_deg": -24.9,
                                                **overrides})


def kitti_config(level: int, beams: int, overrides: dict):
    """The preset a KITTI row runs with: kitti_hdl64 at downsampling step `level`, or (beams > 0) beams_config."""
    return (beams_config(beams, overrides) if beams else
            line_odom_core.load_config("kitti_hdl64", {"downsample": level, **overrides}))


def kitti_beams(data, i: int, beams: int) -> tuple[np.ndarray, np.ndarray]:
    """Scan i with every (64 / beams)-th laser and all its azimuth steps, as a `beams`-beam LiDAR gives it: (xyz,
    ring in [0, beams))."""
    from line_odom.bags import kitti_rings

    points = data.points(i)
    ring = kitti_rings(points)
    keep = ring % (64 // beams) == 0
    return np.ascontiguousarray(points[keep, :3], dtype=np.float64), (ring[keep] // (64 // beams)).astype(np.int32)


STOP_AND_GO = "stop_and_go"
# Runs whose official ground truth disagrees with their scans (the data's README): translation is judged against the
# scans' own motion, registered densely (dense_reference), rotation against the ground truth.
GT_DISAGREES = ("00", "08")
_DENSE: dict[str, np.ndarray] = {}


def dense_reference(name: str, data) -> np.ndarray:
    """Poses chained from each frame pair registered with every point, point-to-plane, from the ground truth's motion
    (bench/gt_consistency.py's aligner): the scans' own motion."""
    if name not in _DENSE:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from gt_consistency import point_to_plane

        poses = [np.eye(4)]
        for i in range(1, len(data)):
            truth = np.linalg.inv(data.poses[i - 1]) @ data.poses[i]
            poses.append(poses[-1] @ point_to_plane(data.xyz(i).astype(np.float64), data.xyz(i - 1).astype(np.float64),
                                                    truth))
        _DENSE[name] = np.array(poses)
    return _DENSE[name]


def default_runs() -> list[str]:
    """Every KITTI-layout run in ../shared/data: the odometry sequences and the raw stop-and-go drive."""
    from line_odom.datasets import SHARED_DATA

    sequences = sorted(p.name for p in (SHARED_DATA / "kitti_odometry_mini" / "sequences").glob("*") if p.is_dir())
    return sequences + ([STOP_AND_GO] if (SHARED_DATA / "kitti_raw_stop_and_go").is_dir() else [])


def open_run(name: str, frames: int | None):
    """A KITTI sequence of the shared set ("00"), the stop-and-go drive, or any directory in the KITTI odometry layout
    (velodyne/, times.txt, calib.txt, and poses_gt.txt or reference_poses.txt: poses to judge against)."""
    from pathlib import Path

    from line_odom.datasets import SHARED_DATA, KittiSequence, read_kitti_poses

    if name == STOP_AND_GO:
        root = SHARED_DATA / "kitti_raw_stop_and_go"
    elif Path(name).is_dir():
        root = Path(name)
    else:
        return kitti_sequence(name, frames)
    data = KittiSequence.open(root, frames)
    if data.poses is None and (root / "reference_poses.txt").exists():
        Tr_inv = np.linalg.inv(data.Tr)
        data.poses = np.stack([Tr_inv @ P @ data.Tr for P in read_kitti_poses(root / "reference_poses.txt")[: len(data)]])
    if data.poses is None:
        raise SystemExit(f"{root}: no poses_gt.txt or reference_poses.txt to judge the run against")
    return data


def run_name(name: str) -> str:
    from pathlib import Path

    return Path(name).name if Path(name).is_dir() else name


def genz_available() -> bool:
    try:
        import genz_icp  # noqa: F401
    except ImportError:
        return False
    return True


def genz_odometry(max_range: float):
    from genz_icp.config import load_config
    from genz_icp.genz_icp import GenZICP

    config = load_config(None)
    config.data.deskew = False
    config.data.max_range = max_range
    config.registration.max_num_threads = 1  # as line_odom's presets and KISS-ICP here: times compare one thread each
    return GenZICP(config)


def peer_pose(odom) -> np.ndarray:
    return (odom.last_pose if hasattr(odom, "last_pose") else odom.poses[-1]).copy()


@dataclasses.dataclass(frozen=True)
class Playback:
    """How a KITTI run is played, beyond the speeds and starts it holds: backwards (from its end, each interval
    kept), from scan `start` of that (counting from 0), every `stride`-th scan of that (stamps kept). Rows are named
    after it."""
    stride: int = 1
    start: int = 0
    backwards: bool = False
    mount: tuple[float, float, float] | None = None  # roll, pitch, yaw (deg) of the sensor turned on its mount
    view: float | None = None  # deg of azimuth each scan keeps, centred ahead (x): the vehicle blocks the rest
    firing_rings: bool = False  # the ring field numbered in firing order (firing_order_rings), not top to bottom
    stamp_jitter_ms: float = 0.0  # each stamp moved by up to this much either way (a driver stamping on arrival)

    def apply(self, data):
        data = data.played_backwards() if self.backwards else data
        data = data.from_scan(self.start) if self.start else data
        data = data.every_kth_scan(self.stride)
        if self.stamp_jitter_ms:
            # Uniform, seeded: every run and method sees the same stamps. The poses judged against stay the run's.
            jitter = np.random.default_rng(0).uniform(-1.0, 1.0, len(data)) * self.stamp_jitter_ms * 1e-3
            data = dataclasses.replace(data, times=np.asarray(data.times, dtype=float) + jitter)
        return data

    def suffix(self) -> str:
        return ((" backwards" if self.backwards else "") + (f" from {self.start}" if self.start else "") +
                (f" x{self.stride}" if self.stride > 1 else "") +
                (" mount {:g}/{:g}/{:g}".format(*self.mount) if self.mount else "") +
                (f" view {self.view:g}" if self.view else "") + (" firing rings" if self.firing_rings else "") +
                (f" jitter {self.stamp_jitter_ms:g} ms" if self.stamp_jitter_ms else ""))

    def mount_transform(self) -> np.ndarray | None:
        """The 4x4 rotation M taking the scans' frame to the turned sensor's: points p -> R p, a motion D -> M D M^T."""
        if not self.mount:
            return None
        from scipy.spatial.transform import Rotation

        m = np.eye(4)
        m[:3, :3] = Rotation.from_euler("xyz", self.mount, degrees=True).as_matrix()
        return m

    def scan(self, data, i: int, beams: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Scan i of the played run as run_kitti feeds it (mounted_scan with this playback's mount, view and rings)."""
        return mounted_scan(data, i, beams, self.mount_transform(), self.view, self.firing_rings)

    def mounted(self, poses: np.ndarray | None) -> np.ndarray | None:
        """The scans' poses as the turned sensor's (M P M^T; as they are without a mount)."""
        mount = self.mount_transform()
        return poses if mount is None or poses is None else np.array([mount @ p @ mount.T for p in poses])


def firing_order_rings(ring_from_top: np.ndarray, beams: int) -> np.ndarray:
    """Rings numbered as a VLP-16 or an HDL-32E numbers its lasers, in firing order: laser 2k is the k-th beam from the
    bottom, laser 2k + 1 the (beams / 2 + k)-th (-15, +1, -13, +3 ... deg on a VLP-16)."""
    from_bottom = beams - 1 - ring_from_top
    laser = np.where(from_bottom < beams // 2, 2 * from_bottom, 2 * (from_bottom - beams // 2) + 1)
    return laser.astype(np.int32)


def mounted_scan(data, i: int, beams: int, mount: np.ndarray | None, view: float | None = None,
                 firing_rings: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Scan i as run_kitti feeds it: `beams` of its lasers (0: all), within `view` deg of azimuth centred ahead (None:
    all), turned by `mount` (mount_transform). A turned scan comes with its rings (from the file's order): a sensor's
    rows are fixed to it, not to the scene's elevation angles. `firing_rings`: the rings numbered in firing order
    (firing_order_rings)."""
    if not beams and mount is None and not firing_rings:
        xyz, ring = data.xyz(i), None
    else:
        xyz, ring = kitti_beams(data, i, beams or 64)
        if firing_rings:
            ring = firing_order_rings(ring, beams or 64)
    if view is not None:
        seen = np.abs(np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))) <= 0.5 * view
        xyz, ring = np.ascontiguousarray(xyz[seen]), None if ring is None else ring[seen]
    if mount is not None:
        xyz = np.ascontiguousarray(xyz @ mount[:3, :3].T)
    return xyz, ring


def run_kitti(seq: str, level: int, frames: int | None, kiss: bool, overrides: dict, beams: int = 0,
              playback: Playback = Playback()) -> Row:
    """KITTI at downsampling step `level` with kitti_hdl64, or (beams > 0) with `beams` of its lasers with vlp16; played
    as `playback` says (its row named "<run><playback.suffix()>")."""
    data = open_run(seq, frames)
    try:
        data = playback.apply(data)
    except ValueError as err:
        raise SystemExit(f"{seq}: --kitti-start {playback.start}: {err}")
    if len(data) < 2:
        raise SystemExit(f"{seq}: {len(data)} scan to play (--kitti-start {playback.start}, --kitti-stride "
                         f"{playback.stride}); expected at least 2")
    label = run_name(seq) + playback.suffix()
    odom = line_odom_core.Odometry(kitti_config(level, beams, overrides))
    lo = Run([], [], [])
    kiss_run = Run([], [], []) if kiss else None
    kiss_odom = kiss_odometry(100.0) if kiss else None
    genz_run = Run([], [], []) if kiss and genz_available() else None
    genz_odom = genz_odometry(100.0) if genz_run else None
    for i in range(len(data)):
        xyz, ring = playback.scan(data, i, beams)
        t0 = time.perf_counter()
        result = odom.register_points(xyz, float(data.times[i]), ring=ring)
        lo.ms.append((time.perf_counter() - t0) * 1e3)
        lo.poses.append(result.pose)
        lo.stats.append(result.stats)
        if kiss_odom is not None:
            pts = odom.downsampled_points(xyz, ring=ring) if level > 1 else xyz.astype(np.float64)
            t0 = time.perf_counter()
            kiss_odom.register_frame(pts, np.zeros(len(pts)))
            kiss_run.ms.append((time.perf_counter() - t0) * 1e3)
            kiss_run.poses.append(kiss_odom.last_pose.copy())
            if genz_odom is not None:
                t0 = time.perf_counter()
                genz_odom.register_frame(pts, np.zeros(len(pts)))
                genz_run.ms.append((time.perf_counter() - t0) * 1e3)
                genz_run.poses.append(peer_pose(genz_odom))
    judged = run_name(seq) in GT_DISAGREES and data.poses is not None

    ground_truth = playback.mounted(data.poses)
    dense = playback.mounted(dense_reference(label, data)) if judged else None

    def errors(poses):
        t, r = frame_errors(np.array(poses), ground_truth)
        if judged:  # translation against the scans' own motion, rotation against the ground truth
            t = frame_errors(np.array(poses), dense)[0]
        return t, r

    lo_frames = errors(lo.poses)
    kiss_frames = errors(kiss_run.poses) if kiss_run else None
    genz_frames = errors(genz_run.poses) if genz_run else None
    row = Row("kitti", label, level, len(data), summary(lo_frames), summary(kiss_frames) if kiss_frames else None,
              steady_ms(lo.ms), steady_ms(kiss_run.ms) if kiss_run else None,
              sum(s["degenerate"] for s in lo.stats), beams, lo_frames, kiss_frames)
    row.genz = summary(genz_frames) if genz_frames else None
    row.genz_ms = steady_ms(genz_run.ms) if genz_run else None
    reference = dense if judged else ground_truth
    row.motion = float(np.mean(frame_motions(reference)))
    row.flagged, row.gross = flagged_and_gross(lo.stats, lo_frames[0], reference)
    row.dense_reference = judged
    row.kiss_reference = run_name(seq) == STOP_AND_GO
    row.source = seq
    row.playback = playback
    return row


def steady_ms(ms: list[float]) -> float:
    """Milliseconds per frame after the first registration (which searches the first motion): the median."""
    return float(np.median(ms[2:] if len(ms) > 2 else ms[1:]))


def flagged_frames(stats: list[dict]) -> np.ndarray:
    """Per frame whether it was flagged: reported degenerate or not registered."""
    return np.array([bool(s["degenerate"]) or not s["registered"] for s in stats], dtype=bool)


def flagged_and_gross(stats: list[dict], t: np.ndarray, gt: np.ndarray) -> tuple[int, int]:
    """Frames flagged (degenerate or not registered), and gross frames not flagged: off by more than max(0.3 m, 30 %
    of the frame's motion)."""
    flagged = flagged_frames(stats[1:])
    gross = t > np.maximum(0.3, 0.3 * frame_motions(gt))
    return int(flagged.sum()), int((gross & ~flagged).sum())


def depth_points(depth: np.ndarray, K: np.ndarray, step: int) -> np.ndarray:
    """The points of every step-th row and column of a depth image, back-projected at their own pixels (the
    same cells the engine keeps when it downsamples)."""
    rows = np.arange(0, depth.shape[0], step)
    cols = np.arange(0, depth.shape[1], step)
    z = depth[np.ix_(rows, cols)].astype(np.float64)
    u, v = np.meshgrid(cols, rows)
    ok = np.isfinite(z) & (z > 0)
    x = (u - K[0, 2]) * z / K[0, 0]
    y = (v - K[1, 2]) * z / K[1, 1]
    return np.stack([x[ok], y[ok], z[ok]], axis=1)


def run_tum(level: int, frames: int, kiss: bool, overrides: dict) -> Row:
    data = tum_sequence(frames)
    config = line_odom_core.load_config("tum_kinect", {"downsample": level, **overrides})
    odom = line_odom_core.Odometry(config)
    lo = Run([], [], [])
    kiss_run = Run([], [], []) if kiss else None
    kiss_odom = kiss_odometry(5.0) if kiss else None
    for i in range(len(data)):
        depth = data.depth(i)
        t0 = time.perf_counter()
        result = odom.register_depth(depth, data.K, float(data.stamps[i]))
        lo.ms.append((time.perf_counter() - t0) * 1e3)
        lo.poses.append(result.pose)
        lo.stats.append(result.stats)
        if kiss_odom is not None:
            pts = depth_points(depth, data.K, level)
            in_range = (pts[:, 2] >= config["sensor.min_range"]) & (pts[:, 2] <= config["sensor.max_range"])
            pts = pts[in_range]
            t0 = time.perf_counter()
            kiss_odom.register_frame(pts, np.zeros(len(pts)))
            kiss_run.ms.append((time.perf_counter() - t0) * 1e3)
            kiss_run.poses.append(kiss_odom.last_pose.copy())
    lo_frames = frame_errors(np.array(lo.poses), data.poses, data.pose_valid)
    kiss_frames = frame_errors(np.array(kiss_run.poses), data.poses, data.pose_valid) if kiss_run else None
    clock = []
    for offset in TUM_CLOCK_OFFSETS:
        gt, valid = data.poses_at_offset(offset)
        lo_at = summary(frame_errors(np.array(lo.poses), gt, valid))
        kiss_at = summary(frame_errors(np.array(kiss_run.poses), gt, valid)) if kiss_run else None
        clock.append((offset, lo_at[0], lo_at[2], *((kiss_at[0], kiss_at[2]) if kiss_at else (None, None))))
    row = Row("tum", "fr1/xyz", level, len(data), summary(lo_frames), summary(kiss_frames) if kiss_frames else None,
              steady_ms(lo.ms), steady_ms(kiss_run.ms) if kiss_run else None,
              sum(s["degenerate"] for s in lo.stats), 0, lo_frames, kiss_frames, clock)
    flagged = np.array([bool(s["degenerate"]) or not s["registered"] for s in lo.stats])
    row.flagged = int(flagged[1:].sum())
    return row


# Per run: the best full-resolution translation of either method (1.1 times it: no goal is set below the noise of the
# poses judged against), filled as the full-resolution rows come.
FLOORS: dict[str, float] = {}


def note_floor(row: Row) -> None:
    if row.dataset == "kitti" and row.level == 1 and not row.beams:
        best = min(row.lo[0], row.kiss[0]) if row.kiss and not row.kiss_reference else row.lo[0]
        FLOORS[row.sequence] = min(FLOORS.get(row.sequence, np.inf), 1.1 * best)


def goal(row: Row) -> tuple[str, bool | None]:
    """The row's goal and whether it is met (None: cannot tell without KISS-ICP): translation <= KISS-ICP's at full
    resolution and with 16 or 32 lasers, <= half of it at 1/36 and 1/64 where KISS-ICP tracks (its mean under 30 % of
    the motion) and under 30 % of the motion where it does not, never below 1.1 times the run's best full-resolution
    translation of either method; rotation <= KISS-ICP's + 0.02 deg; no gross frame unflagged. TUM at 1/100: the
    paper's 5.05 mm and 0.52 deg."""
    lo_t, _, lo_r, _ = row.lo
    if row.dataset == "tum":
        if row.level == 10:
            return "<= 5.05 mm, 0.52 deg", lo_t <= 0.00505 and lo_r <= 0.52
        return "t,r <= KISS", None if row.kiss is None else (lo_t <= row.kiss[0] and lo_r <= row.kiss[2])
    if row.kiss is None:
        return "-", None
    kiss_t, kiss_r = row.kiss[0], row.kiss[2]
    if row.kiss_reference and row.level == 1 and not row.beams:
        return "- (the reference is KISS-ICP's own)", None
    if row.level == 1 or row.beams:
        target, text = kiss_t, "t <= KISS"
    elif kiss_t < 0.3 * row.motion:
        target, text = 0.5 * kiss_t, "t <= KISS/2"
    else:
        target, text = 0.3 * row.motion, "t < 30% motion"
    floor = FLOORS.get(row.sequence, 0.0)
    if target < floor:
        target, text = floor, "t <= 1.1 best full"
    met = lo_t <= target and lo_r <= kiss_r + 0.02 and row.gross <= 0
    return f"{text}, r <= KISS+0.02, 0 gross", met


def time_goal(row: Row) -> tuple[str, bool | None]:
    """Steady milliseconds per frame <= KISS-ICP's on every row, <= half of it at full resolution."""
    if row.kiss_ms is None:
        return "-", None
    if row.level == 1 and not row.beams:
        return "ms <= KISS/2", row.lo_ms <= 0.5 * row.kiss_ms
    return "ms <= KISS", row.lo_ms <= row.kiss_ms


HEAD = (f"{'data':5} {'seq':11} {'res':5} {'n':>3} | {'line_odom mean/max t [m]':>24} {'mean/max r [deg]':>17} "
        f"{'ms':>6} {'flg':>3} {'grs':>3} | {'KISS-ICP mean/max t [m]':>23} {'mean/max r [deg]':>17} {'ms':>6} | "
        f"{'GenZ-ICP t / r':>16} {'ms':>6} | {'paper t/r':>14} | goal")


def resolution_name(row: Row) -> str:
    if row.beams:
        return f"{row.beams}b"
    levels = KITTI_LEVELS if row.dataset == "kitti" else TUM_LEVELS
    return levels.get(row.level, f"1/{row.level**2}")


def format_row(row: Row) -> str:
    lo_t, lo_tm, lo_r, lo_rm = row.lo
    kiss = (f"{row.kiss[0]:11.4f}/{row.kiss[1]:<11.4f} {row.kiss[2]:8.3f}/{row.kiss[3]:<8.3f} "
            f"{row.kiss_ms:6.1f}") if row.kiss else f"{'n/a':>23} {'':>17} {'':>6}"
    paper = None if row.beams else PAPER.get((row.dataset, row.sequence, row.level))
    paper_text = f"{paper[0]:.4f}/{paper[1]:.3f}" if paper else "-"
    text, met = goal(row)
    verdict = {True: "MET", False: "MISSED", None: "?"}[met]
    time_text, time_met = time_goal(row)
    time_verdict = {True: "met", False: "missed", None: "?"}[time_met]
    genz = f"{row.genz[0]:8.4f}/{row.genz[2]:<7.3f} {row.genz_ms:6.1f}" if row.genz else f"{'n/a':>16} {'':>6}"
    gross = f"{row.gross:3d}" if row.gross >= 0 else f"{'-':>3}"
    return (f"{row.dataset:5} {row.sequence:11} {resolution_name(row):5} {row.frames:3d} | "
            f"{lo_t:12.4f}/{lo_tm:<11.4f} {lo_r:8.3f}/{lo_rm:<8.3f} {row.lo_ms:6.1f} {row.flagged:3d} {gross} | "
            f"{kiss} | {genz} | {paper_text:>14} | {text if text == '-' else f'{text}: {verdict}'}"
            f"{'' if time_text == '-' else f'; {time_text}: {time_verdict}'}")


def write_markdown(rows: list[Row], path: str, command: str) -> None:
    """The summary as docs/RESULTS.md's "Accuracy" table, with its provenance line."""
    import platform
    import subprocess
    from datetime import datetime, timezone

    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
        commit += " (with uncommitted changes)" if dirty else ""
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"Provenance: `{command}`, commit {commit}, {when}, {platform.node()} ({platform.machine()}, "
             f"{__import__('os').cpu_count()} cores), Python {platform.python_version()}.", "",
             "| run | line_odom t mean/max, r mean/max | ms | flagged | gross unflagged | KISS-ICP t / r | ms | "
             "GenZ-ICP t / r (ms) | goal | time |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lo_t, lo_tm, lo_r, lo_rm = row.lo
        unit = 1e3 if row.dataset == "tum" else 1.0
        name = f"{row.dataset} {row.sequence} {resolution_name(row)}" + (" *" if row.dense_reference else "")
        kiss = f"{row.kiss[0] * unit:.4f} / {row.kiss[2]:.3f}" if row.kiss else "-"
        kiss_ms = f"{row.kiss_ms:.1f}" if row.kiss_ms is not None else "-"
        genz = f"{row.genz[0] * unit:.4f} / {row.genz[2]:.3f} ({row.genz_ms:.1f})" if row.genz else "-"
        text, met = goal(row)
        time_text, time_met = time_goal(row)
        verdict = {True: "met", False: "**missed**", None: "-"}
        gross = str(row.gross) if row.gross >= 0 else "-"
        lines.append(f"| {name} | {lo_t * unit:.4f}/{lo_tm * unit:.4f} / {lo_r:.3f}/{lo_rm:.3f} | {row.lo_ms:.1f} | "
                     f"{row.flagged} | {gross} | {kiss} | {kiss_ms} | {genz} | {verdict[met]} | "
                     f"{verdict[time_met]} |")
    Path(path).write_text("\n".join(lines) + "\n")


def print_table(rows: list[Row]) -> None:
    print(HEAD)
    print("-" * len(HEAD))
    for row in rows:
        print(format_row(row))


def resolved(mean: float, low: float, high: float, unit: str) -> str:
    if low > 0.0:
        return f"KISS-ICP lower by {mean:.4f} {unit} [{low:.4f}, {high:.4f}]"
    if high < 0.0:
        return f"line_odom lower by {-mean:.4f} {unit} [{-high:.4f}, {-low:.4f}]"
    return f"not resolved: {mean:+.4f} {unit} [{low:+.4f}, {high:+.4f}]"


def print_clock(rows: list[Row]) -> None:
    """TUM rows again with the ground truth read at the depth stamps + an offset (the goals use offset 0)."""
    clocked = [row for row in rows if row.clock]
    if not clocked:
        return
    print("\nTUM with the ground truth at the depth stamp + offset (interpolated; the goals and the table above: 0 ms), "
          "mean t [mm] / r [deg]")
    print(f"{'res':5} {'offset ms':>9} | {'line_odom':>16} | {'KISS-ICP':>16}")
    for row in clocked:
        for offset, lo_t, lo_r, kiss_t, kiss_r in row.clock:
            kiss = f"{kiss_t * 1e3:7.2f} / {kiss_r:6.3f}" if kiss_t is not None else f"{'n/a':>16}"
            print(f"{resolution_name(row):5} {offset * 1e3:9.0f} | {lo_t * 1e3:7.2f} / {lo_r:6.3f} | {kiss}")


def print_paired(rows: list[Row]) -> None:
    """Which method's mean is lower, as far as the row's frame pairs tell (paired bootstrap, line_odom - KISS-ICP)."""
    paired = [row for row in rows if row.lo_frames is not None and row.kiss_frames is not None]
    if not paired:
        return
    print("\nline_odom - KISS-ICP per frame pair, mean and 95 % bootstrap interval (BCa, paired; an interval spanning 0: "
          "these frames do not tell which error is lower)")
    for row in paired:
        t = paired_difference(row.lo_frames[0], row.kiss_frames[0])
        r = paired_difference(row.lo_frames[1], row.kiss_frames[1])
        print(f"{row.dataset:5} {row.sequence:7} {resolution_name(row):5} {len(row.lo_frames[0]):3d} pairs | "
              f"t: {resolved(*t, 'm')} | r: {resolved(*r, 'deg')}")


SIM_PRESETS = {"hdl64": "kitti_hdl64", "vlp16": "vlp16", "os128": "ouster_os128"}


def simulated_drive(frames: int, sensor: str, distorted: str, swing=None):
    """The simulated street (10 m/s, 10 Hz, 1 cm range noise; `distorted` non-empty: sweeps cast while the sensor
    moves; `swing` (share, period s): the speed swinging by +-that share over that period instead of +-10 % over
    15-40 s), its ground-truth poses and the sensor's preset; prints the drive's heading line."""
    from line_odom import sim

    swing_kw = {"speed_variation": swing[0], "speed_period": swing[1]} if swing else {}  # else the street's own
    run = sim.make("street", frames=frames, seed=0, noise_std=0.01, sensor=sensor, motion_distortion=bool(distorted),
                   **swing_kw)
    gt = np.array(run.trajectory.poses)
    length = float(np.sum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)))
    preset = SIM_PRESETS[sensor]
    swinging = f", speed 10 m/s +-{100 * swing[0]:.0f} % every {swing[1]:g} s" if swing else ""
    print(f"\nsimulated street drive{distorted}{swinging}, {sensor} ({preset}): {frames} scans, {length:.0f} m (KITTI "
          f"devkit metric over 100..800 m segments when >= 100 m)")
    return run, gt, preset


def sim_configs(preset: str, sensor: str, levels, overrides: dict):
    """The preset's config at each downsampling step of `levels` for the HDL-64E, at the preset's own for the others."""
    for level in (levels if sensor == "hdl64" else (None,)):
        yield line_odom_core.load_config(preset, {**({} if level is None else {"downsample": level}), **overrides})


def run_sim(kiss: bool, overrides: dict, frames: int, levels=(1, 6), sensor: str = "hdl64", swing=None) -> None:
    """Simulated street drive (line_odom.sim: 10 m/s, 10 Hz, 1 cm range noise), KITTI devkit metric. HDL-64 with
    kitti_hdl64 at each of `levels`; VLP-16 / OS-128 with their own presets at the presets' resolution (the goals are
    for the HDL-64 rows)."""
    from line_odom.metrics import kitti_errors

    run, gt, preset = simulated_drive(frames, sensor, "", swing)
    print(f"{'res':5} | {'line_odom t_err [%]':>20} {'r_err [deg/m]':>14} {'RPE t [m]':>10} {'ms':>6} | "
          f"{'KISS-ICP t_err [%]':>19} {'r_err [deg/m]':>14} {'RPE t [m]':>10} {'ms':>6} | goal", flush=True)
    for config in sim_configs(preset, sensor, levels, overrides):
        step = config["downsample"]
        odom = line_odom_core.Odometry(config)
        kiss_odom = kiss_odometry(100.0) if kiss else None
        est, kiss_est, ms, kiss_ms = [], [], [], []
        for frame in run:
            scan = frame.data
            ring = scan.ring.astype(np.int32)
            t0 = time.perf_counter()
            est.append(odom.register_points(scan.points, frame.stamp, ring=ring).pose)
            ms.append((time.perf_counter() - t0) * 1e3)
            if kiss_odom is not None:
                pts = odom.downsampled_points(scan.points, ring=ring) if step > 1 else scan.points.astype(float)
                t0 = time.perf_counter()
                kiss_odom.register_frame(pts, np.zeros(len(pts)))
                kiss_ms.append((time.perf_counter() - t0) * 1e3)
                kiss_est.append(kiss_odom.last_pose.copy())
        scores = kitti_errors(np.array(est), gt)
        rpe_t = summary(frame_errors(np.array(est), gt))[0]
        lo_text = (f"{scores[0]:20.3f} {scores[1]:14.5f}" if scores else f"{'too short':>20} {'':>14}") + \
            f" {rpe_t:10.4f} {np.mean(ms[1:]):6.1f}"
        k_text = f"{'n/a':>19} {'':>14} {'':>10} {'':>6}"
        if kiss_odom is not None:
            kscores = kitti_errors(np.array(kiss_est), gt)
            k_rpe = summary(frame_errors(np.array(kiss_est), gt))[0]
            k_text = (f"{kscores[0]:19.3f} {kscores[1]:14.5f}" if kscores else f"{'too short':>19} {'':>14}") + \
                f" {k_rpe:10.4f} {np.mean(kiss_ms[1:]):6.1f}"
        if sensor != "hdl64":
            name, goal = f"1/{step * step}" if step > 1 else "full", "-"
        else:
            goal_pct = 1.0 if step == 1 else 3.0
            verdict = "?" if scores is None else ("MET" if scores[0] <= goal_pct else "MISSED")
            name, goal = KITTI_LEVELS[step], f"t_err <= {goal_pct}%: {verdict}"
        print(f"{name:5} | {lo_text} | {k_text} | {goal}", flush=True)


def run_sim_distorted(kiss: bool, overrides: dict, frames: int, levels=(1, 6), sensor: str = "hdl64",
                      stamp_at: str = "start", swing=None) -> None:
    """The simulated street drive with sweeps cast while the sensor moves (each column from the pose at its firing
    time, 10 m/s: up to 1 m across a sweep): line_odom given each point's time (sensor.deskew) and without it,
    KISS-ICP with its deskew on (the same times, as fractions of the sweep) and off, on the same points.
    `stamp_at` "end": each scan stamped at its sweep's end (times before the stamp, the pose there the truth; a driver
    stamping the last packet), line_odom only; "start": as simulated."""
    from line_odom.metrics import kitti_errors

    end = stamp_at == "end"
    run, gt, preset = simulated_drive(frames, sensor, " with motion-distorted sweeps" +
                                      (", stamped at the sweep's end" if end else ""), swing)
    period = 1.0 / run.sensor.rate_hz
    if end:
        kiss = False
        gt = np.array([run.trajectory.pose_at(stamp + period) for stamp in run.trajectory.stamps])
    print(f"{'res':5} {'method':24} | {'t_err [%]':>10} {'r_err [deg/m]':>14} {'RPE t [m]':>10} {'r [deg]':>8} "
          f"{'ms':>6}", flush=True)
    for config in sim_configs(preset, sensor, levels, overrides):
        step = config["downsample"]
        methods = {"line_odom deskewed": line_odom_core.Odometry(config),
                   "line_odom as measured": line_odom_core.Odometry(config)}
        if kiss:
            methods["KISS-ICP deskew on"] = kiss_odometry(100.0, deskew=True)
            methods["KISS-ICP deskew off"] = kiss_odometry(100.0)
        poses = {name: [] for name in methods}
        ms = {name: [] for name in methods}
        for frame in run:
            scan = frame.data
            ring = scan.ring.astype(np.int32)
            sweep_fraction = scan.time.astype(np.float64) * run.sensor.rate_hz
            for name, method in methods.items():
                t0 = time.perf_counter()
                if name.startswith("line_odom"):
                    times = (scan.time.astype(np.float64) - (period if end else 0.0)
                             if name == "line_odom deskewed" else None)
                    stamp = frame.stamp + (period if end else 0.0)
                    poses[name].append(method.register_points(scan.points, stamp, ring=ring, time=times).pose)
                else:
                    keep = (np.arange(len(scan.points)) if step == 1 else
                            np.flatnonzero((scan.ring % step == 0) & (scan.column % step == 0)))
                    method.register_frame(scan.points[keep].astype(np.float64), sweep_fraction[keep])
                    poses[name].append(method.last_pose.copy())
                ms[name].append((time.perf_counter() - t0) * 1e3)
        name_level = "full" if step == 1 else f"1/{step * step}"
        for name in methods:
            est = np.array(poses[name])
            scores = kitti_errors(est, gt)
            err = summary(frame_errors(est, gt))
            score_text = f"{scores[0]:10.3f} {scores[1]:14.5f}" if scores else f"{'-':>10} {'':>14}"
            print(f"{name_level:5} {name:24} | {score_text} {err[0]:10.4f} {err[2]:8.4f} {np.mean(ms[name][1:]):6.1f}",
                  flush=True)


def print_seed_spread(rows: list[Row], seeds: int, args, overrides: dict) -> None:
    """line_odom again with RANSAC seeds 1..seeds-1 on each row's frames (KISS-ICP is deterministic: its numbers
    from the seed-0 run); each goal judged per seed against the same KISS-ICP row."""
    print(f"\nline_odom over RANSAC seeds 0..{seeds - 1} (mean of the per-seed means; the table above is seed 0, "
          f"the presets' seed)")
    print(f"{'data':5} {'seq':7} {'res':5} | {'seed 0 t / r':>17} | {'mean t / r':>17} | {'t min-max':>15} | "
          f"{'r min-max':>13} | goal met for")
    for row in rows:
        per_seed = [row]
        for seed in range(1, seeds):
            over = {**overrides, "seed": seed}
            again = (run_kitti(row.source, row.level, args.kitti_frames, False, over, row.beams, row.playback)
                     if row.dataset == "kitti"
                     else run_tum(row.level, args.tum_frames, False, over))
            per_seed.append(dataclasses.replace(again, kiss=row.kiss, kiss_ms=row.kiss_ms))
        t = np.array([r.lo[0] for r in per_seed])
        r = np.array([r.lo[2] for r in per_seed])
        met = [goal(x)[1] for x in per_seed]
        met_text = "-" if row.beams else "?" if None in met else f"{sum(met)} of {seeds} seeds"
        print(f"{row.dataset:5} {row.sequence:7} {resolution_name(row):5} | "
              f"{t[0]:8.4f} / {r[0]:6.3f} | {t.mean():8.4f} / {r.mean():6.3f} | {t.min():6.4f}-{t.max():6.4f} | "
              f"{r.min():5.3f}-{r.max():5.3f} | {met_text} ({goal(row)[0]})", flush=True)


def add_playback_arguments(parser: argparse.ArgumentParser) -> None:
    """--kitti-stride, --kitti-start, --kitti-backwards, --kitti-mount, --kitti-view, --kitti-firing-rings,
    --kitti-stamp-jitter: how each KITTI run is played."""
    parser.add_argument("--kitti-stride", type=int, default=1, metavar="K",
                        help="every K-th scan of each run, stamps kept: each scan moves K times as far (rows named "
                             "'<run> xK'; the runs beyond the speeds they hold)")
    parser.add_argument("--kitti-start", type=int, default=0, metavar="S",
                        help="each run from scan S on, counting from 0 (after --kitti-backwards): a cold start "
                             "mid-drive (rows named '<run> from S')")
    parser.add_argument("--kitti-backwards", action="store_true",
                        help="each run played backwards from its end, each interval kept: stops become starts, "
                             "braking becomes accelerating (rows named '<run> backwards')")
    parser.add_argument("--kitti-mount", nargs=3, type=float, metavar=("ROLL", "PITCH", "YAW"),
                        help="every scan turned as a sensor turned on its mount by these angles (deg, about x, y, z), "
                             "its rings from the file's order, the poses judged in the turned frame (rows named "
                             "'<run> mount R/P/Y'): a tilted sensor, and other samplings of the same scenes")
    parser.add_argument("--kitti-view", type=float, metavar="DEG",
                        help="every scan kept to the points within DEG of azimuth centred ahead (x), DEG in (0, 360]: "
                             "a sensor the vehicle blocks behind it (rows named '<run> view DEG')")
    parser.add_argument("--kitti-stamp-jitter", type=float, default=0.0, metavar="MS",
                        help="every scan's stamp moved by a seeded uniform draw of up to MS milliseconds either way, "
                             "as a driver stamping scans on arrival (rows named '<run> jitter MS ms')")
    parser.add_argument("--kitti-firing-rings", action="store_true",
                        help="every scan given its ring field numbered in firing order, as a VLP-16 or an HDL-32E "
                             "numbers its lasers, not from the top beam (rows named '<run> firing rings')")


def playback_from(parser: argparse.ArgumentParser, args: argparse.Namespace) -> Playback:
    """The Playback that add_playback_arguments' arguments ask for (a bad value is refused naming its argument)."""
    if args.kitti_stride < 1:
        parser.error(f"--kitti-stride {args.kitti_stride}: expected a whole number of scans >= 1")
    if args.kitti_start < 0:
        parser.error(f"--kitti-start {args.kitti_start}: expected a scan index >= 0")
    if args.kitti_view is not None and not 0.0 < args.kitti_view <= 360.0:
        parser.error(f"--kitti-view {args.kitti_view:g}: expected degrees of azimuth in (0, 360]")
    if not 0.0 <= args.kitti_stamp_jitter < 50.0:
        parser.error(f"--kitti-stamp-jitter {args.kitti_stamp_jitter:g}: expected milliseconds in [0, 50), below half "
                     "a scan's interval")
    return Playback(args.kitti_stride, args.kitti_start, args.kitti_backwards,
                    tuple(args.kitti_mount) if args.kitti_mount else None, args.kitti_view, args.kitti_firing_rings,
                    args.kitti_stamp_jitter)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", choices=("kitti", "tum", "sim"), help="run one dataset (sim: the simulated drive)")
    parser.add_argument("--kitti", nargs="+", default=None,
                        help="KITTI sequences of the shared set and 'stop_and_go' (default: every run there)")
    parser.add_argument("--data", nargs="+", default=[], metavar="DIR",
                        help="also these directories in the KITTI odometry layout (velodyne/, times.txt, calib.txt, "
                             "poses_gt.txt or reference_poses.txt), run as the shared sequences are")
    parser.add_argument("--kitti-levels", nargs="*", type=int, default=[1, 6, 8],
                        help="downsampling steps (none: skip)")
    parser.add_argument("--kitti-frames", type=int, default=None, help="frames per sequence (default all)")
    add_playback_arguments(parser)
    parser.add_argument("--kitti-beams", nargs="*", type=int, default=[16, 32], choices=(8, 16, 32),
                        help="also KITTI kept to this many of its 64 lasers (every 4th for 16), every azimuth step, "
                             "with the vlp16 preset: a real 16-beam-like scan (none: skip)")
    parser.add_argument("--tum-levels", nargs="+", type=int, default=[1, 10])
    parser.add_argument("--tum-frames", type=int, default=300)
    parser.add_argument("--no-kiss", action="store_true", help="line_odom only")
    parser.add_argument("--sim", action="store_true", help="also the simulated street drive")
    parser.add_argument("--sim-frames", type=int, default=1000, help="simulated scans (10 m/s, 10 Hz: 1000 = 1 km)")
    parser.add_argument("--sim-sensor", choices=tuple(SIM_PRESETS), default="hdl64",
                        help="simulated LiDAR (vlp16, os128: their own presets at the presets' resolution)")
    parser.add_argument("--sim-levels", nargs="+", type=int, default=[1, 6], help="downsampling steps of the sim run")
    parser.add_argument("--sim-distortion", action="store_true",
                        help="the simulated drive with sweeps cast while the sensor moves: line_odom with and without "
                             "the points' times (sensor.deskew), KISS-ICP with deskew on and off")
    parser.add_argument("--sim-stamp", choices=("start", "end"), default="start",
                        help="with --sim-distortion: each scan stamped at its sweep's start (as simulated) or end "
                             "(line_odom only)")
    parser.add_argument("--sim-speed-swing", nargs=2, type=float, metavar=("SHARE", "PERIOD"),
                        help="the simulated drive's speed swinging by +-SHARE of 10 m/s every PERIOD s (default: "
                             "+-0.1 over 15-40 s), e.g. 0.5 4: 5-15 m/s, up to 7.9 m/s^2")
    parser.add_argument("--seeds", type=int, default=1,
                        help="also run line_odom with RANSAC seeds 1..N-1 and print the spread (nine frame pairs "
                             "per KITTI row: one sample can move a mean)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="engine setting overrides (dotted names), e.g. ransac.max_iterations=500")
    parser.add_argument("--markdown", metavar="FILE",
                        help="also write the summary as docs/RESULTS.md's markdown table with its provenance line")
    args = parser.parse_args(argv)
    args.kitti = (args.kitti if args.kitti is not None else default_runs()) + args.data
    if args.only == "sim":
        args.sim = True
    overrides, kiss = overrides_and_kiss(parser, args)
    playback = playback_from(parser, args)
    print(f"line_odom_core {line_odom_core.__version__}; overrides {overrides or 'none'}; "
          f"KISS-ICP {'on' if kiss else 'off'} (deskew off, voxel = max_range / 100)")
    rows: list[Row] = []
    if args.only != "sim":
        print(HEAD, flush=True)
    if args.only in (None, "kitti"):
        for level in args.kitti_levels:
            for seq in args.kitti:
                rows.append(run_kitti(seq, level, args.kitti_frames, kiss, overrides, playback=playback))
                note_floor(rows[-1])
                print(format_row(rows[-1]), flush=True)
        for beams in args.kitti_beams:
            for seq in args.kitti:
                rows.append(run_kitti(seq, 1, args.kitti_frames, kiss, overrides, beams, playback))
                print(format_row(rows[-1]), flush=True)
    if args.only in (None, "tum"):
        for level in args.tum_levels:
            rows.append(run_tum(level, args.tum_frames, kiss, overrides))
            print(format_row(rows[-1]), flush=True)
    if rows:
        print("\nsummary (ms: steady, the median per frame after the first registration, Python call included; flg: "
              "frames flagged, degenerate or not registered; grs: gross frames not flagged, off by more than max(0.3 m, "
              "30 % of the motion); peers on the same points, deskew off)")
        print_table(rows)
        print_paired(rows)
        print_clock(rows)
        if args.seeds > 1:
            print_seed_spread(rows, args.seeds, args, overrides)
        if args.markdown:
            write_markdown(rows, args.markdown, ".venv/bin/python bench/accuracy.py " + " ".join(argv or sys.argv[1:]))
    if args.sim:
        if args.sim_distortion:
            run_sim_distorted(kiss, overrides, args.sim_frames, tuple(args.sim_levels), args.sim_sensor, args.sim_stamp,
                              args.sim_speed_swing)
        else:
            run_sim(kiss, overrides, args.sim_frames, tuple(args.sim_levels), args.sim_sensor, args.sim_speed_swing)
    return 0


if __name__ == "__main__":
    sys.exit(main())
