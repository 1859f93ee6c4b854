#!/usr/bin/env python3
"""Do the shared KITTI scans agree with their ground truth? Scan-to-scan alignment under GT vs the estimates.

    .venv/bin/python bench/gt_consistency.py              # KITTI 00/04/07, line_odom and KISS-ICP at full resolution
    .venv/bin/python bench/gt_consistency.py --no-kiss

For every frame pair the non-ground points of scan i-1 (5-40 m horizontal range, z > -1.3 m in the LiDAR frame)
are moved into scan i by a relative motion and matched to their nearest neighbour in scan i (all points). A motion
that describes the scans leaves them close: the table prints the median nearest-neighbour distance and the share
within 5 cm and 10 cm, per sequence, for the ground-truth motion and for each method's estimate, and the forward
motion per frame. Where both methods align the scans much more tightly than the ground truth does, the RPE of
that sequence measures the ground truth's disagreement with the scans, not the methods' accuracy (bench/accuracy.py
goals on KITTI 00, docs/RESULTS.md).

More tables separate the ground truth's rotation from its translation and its errors from the methods':
- The scans aligned by one motion's rotation with another's translation (GT rotation + the method's translation, the
  method's rotation + GT translation): the part of the ground truth that leaves the scans less aligned is the part
  that disagrees with them.
- With KISS-ICP, the three-cornered hat (Gray and Allan, 1974; clock stability): three estimates of the same motion
  with independent errors give each one's own error from their pairwise differences,
  var(A) = (var(A - B) + var(A - C) - var(B - C)) / 2, with var the mean squared norm of a frame's difference (m, deg).
  Nine frame pairs make these rough (a negative variance prints as a negative root); the mean signed rotation
  difference to the ground truth (roll, pitch, yaw per frame) shows biases. The hat assumes independent errors: a
  ground truth that smooths the motion shares its error with a method that leans on its motion model.
- The scans' own motion: each pair registered at full resolution by a dense aligner started at the ground truth
  (point-to-plane ICP below; KISS-ICP's point-to-point aligner too when installed), its mean forward motion and its
  RPE against the ground truth. Started at the answer, with every point, it scores what recovering the scans' motion
  exactly scores: a goal below it asks an estimate to leave the scans' motion in the ground truth's direction.
- Each motion's spread about its own mean over the clip (rms over frames of the per-frame motion minus the mean
  motion), and the RPE of a constant motion (line_odom's mean motion, every frame): where the ground truth moves at
  one constant velocity while the methods see the motion vary, and agree on it, the constant motion scores better
  than either method, and the RPE measures how constant an estimate is.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

sys.path.append(str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import line_odom_core  # noqa: E402
from accuracy import KISS_HINT, kiss_available, kiss_odometry  # noqa: E402
from line_odom.datasets import kitti_sequence  # noqa: E402
from line_odom.metrics import relative_pose_errors  # noqa: E402


def structure_points(xyz: np.ndarray) -> np.ndarray:
    horizontal = np.linalg.norm(xyz[:, :2], axis=1)
    return xyz[(horizontal > 5.0) & (horizontal < 40.0) & (xyz[:, 2] > -1.3)]


def alignment(prev: np.ndarray, tree: cKDTree, T_prev_cur: np.ndarray) -> tuple[float, float, float]:
    """Median NN distance and shares within 5 / 10 cm of `prev` (frame i-1) moved into frame i."""
    T = np.linalg.inv(T_prev_cur)
    d, _ = tree.query(prev @ T[:3, :3].T + T[:3, 3])
    return float(np.median(d)), float(np.mean(d < 0.05)), float(np.mean(d < 0.10))


def relative(poses: list[np.ndarray], i: int) -> np.ndarray:
    return np.linalg.inv(poses[i - 1]) @ poses[i]


def with_translation(rotation_from: np.ndarray, translation_from: np.ndarray) -> np.ndarray:
    T = rotation_from.copy()
    T[:3, 3] = translation_from[:3, 3]
    return T


def differences(a: list[np.ndarray], b: list[np.ndarray]) -> np.ndarray:
    """Per frame pair: (translation m, rotation vector deg) of a's relative motion to b's."""
    out = []
    for i in range(1, len(a)):
        e = np.linalg.inv(relative(a, i)) @ relative(b, i)
        out.append(np.r_[e[:3, 3], np.degrees(Rotation.from_matrix(e[:3, :3]).as_rotvec())])
    return np.array(out)


def signed_root(x: float) -> float:
    return float(np.sign(x) * np.sqrt(abs(x)))


def print_swaps(seq: str, scans: list[np.ndarray], trees: list[cKDTree], motions: dict) -> None:
    gt = motions["GT"]
    for name, poses in motions.items():
        if name == "GT":
            continue
        for label, swap in ((f"GT rot + {name} t", lambda i: with_translation(relative(gt, i), relative(poses, i))),
                            (f"{name} rot + GT t", lambda i: with_translation(relative(poses, i), relative(gt, i)))):
            rows = np.array([alignment(structure_points(scans[i - 1]), trees[i], swap(i))
                             for i in range(1, len(scans))])
            print(f"{seq:4} {label:24} | {rows[:, 0].mean():13.4f} {rows[:, 1].mean():6.3f} {rows[:, 2].mean():7.3f}")


def orthonormal(T: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(T[:3, :3])
    out = T.copy()
    out[:3, :3] = u @ vt
    return out


def voxel_first_points(points: np.ndarray, voxel: float) -> np.ndarray:
    _, first = np.unique(np.floor(points / voxel).astype(np.int64), axis=0, return_index=True)
    return points[np.sort(first)]


def point_to_plane(source: np.ndarray, target: np.ndarray, T: np.ndarray, iterations: int = 30,
                   max_distance: float = 1.0, huber: float = 0.1) -> np.ndarray:
    """T_target_source moving `source` onto the planes of `target`'s 10 nearest points, Gauss-Newton from T.

    Written here: the benchmark's dependencies (numpy, scipy) have no ICP, KISS-ICP's aligner is point-to-point and
    optional, and a second, point-to-plane aligner makes the scans' motion independent of either method."""
    target = voxel_first_points(target, 0.2)
    source = voxel_first_points(source, 0.5)
    tree = cKDTree(target)
    _, neighbours = tree.query(target, k=10)
    centred = target[neighbours] - target[neighbours].mean(axis=1, keepdims=True)
    values, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
    normals = vectors[:, :, 0]
    planar = (values[:, 1] - values[:, 0]) > 0.1 * np.maximum(values[:, 2], 1e-12)
    T = orthonormal(T)
    for _ in range(iterations):
        moved = source @ T[:3, :3].T + T[:3, 3]
        d, j = tree.query(moved, distance_upper_bound=max_distance)
        keep = np.isfinite(d)
        keep[keep] &= planar[j[keep]]
        q, n = moved[keep], normals[j[keep]]
        r = np.einsum("ni,ni->n", q - target[j[keep]], n)
        J = np.hstack([n, np.cross(q, n)])
        w = np.minimum(1.0, huber / np.maximum(np.abs(r), 1e-12))
        step = -np.linalg.solve(J.T @ (J * w[:, None]), J.T @ (w * r))
        dT = np.eye(4)
        dT[:3, :3] = Rotation.from_rotvec(step[3:]).as_matrix()
        dT[:3, 3] = step[:3]
        T = dT @ T
    return T


def kiss_aligner(source: np.ndarray, target: np.ndarray, T: np.ndarray) -> np.ndarray:
    from kiss_icp.mapping import VoxelHashMap
    from kiss_icp.registration import Registration
    from kiss_icp.voxelization import voxel_down_sample

    voxel_map = VoxelHashMap(voxel_size=0.5, max_distance=100.0, max_points_per_voxel=20)
    voxel_map.add_points(voxel_down_sample(target, 0.25))
    registration = Registration(max_num_iterations=500, convergence_criterion=1e-5, max_num_threads=1)
    return registration.align_points_to_map(voxel_down_sample(source, 0.5), voxel_map, orthonormal(T), 1.0, 0.1)


def print_scans_own_motion(seq: str, scans: list[np.ndarray], motions: dict, use_kiss: bool) -> None:
    gt = motions["GT"]
    aligners = {"point-to-plane": point_to_plane, **({"KISS-ICP aligner": kiss_aligner} if use_kiss else {})}
    gt_forward = np.mean([relative(gt, i)[0, 3] for i in range(1, len(scans))])
    for name, align in aligners.items():
        poses = [np.eye(4)]
        for i in range(1, len(scans)):
            poses.append(poses[-1] @ align(scans[i], scans[i - 1], relative(gt, i)))
        t, r = relative_pose_errors(np.array(poses), np.array(gt))
        forward = np.mean([relative(poses, i)[0, 3] for i in range(1, len(scans))])
        print(f"{seq:4} {name:16} | {gt_forward:10.3f} {forward:10.3f} | {t.mean():8.4f} {r.mean():6.3f}")


def motion_vectors(poses: list[np.ndarray]) -> np.ndarray:
    """Per frame pair: (translation m, rotation vector deg) of the relative motion."""
    out = []
    for i in range(1, len(poses)):
        T = relative(poses, i)
        out.append(np.r_[T[:3, 3], np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec())])
    return np.array(out)


def repeated(mean_motion: np.ndarray, frames: int) -> list[np.ndarray]:
    step = np.eye(4)
    step[:3, :3] = Rotation.from_rotvec(np.radians(mean_motion[3:])).as_matrix()
    step[:3, 3] = mean_motion[:3]
    poses = [np.eye(4)]
    for _ in range(frames - 1):
        poses.append(poses[-1] @ step)
    return poses


def print_constancy(seq: str, motions: dict) -> None:
    row = []
    for name, poses in motions.items():
        m = motion_vectors(poses)
        spread = m - m.mean(axis=0)
        row.append(f"{np.sqrt(np.mean(np.sum(spread[:, :3] ** 2, axis=1))):7.4f} "
                   f"{np.sqrt(np.mean(np.sum(spread[:, 3:] ** 2, axis=1))):6.3f}")
    constant = repeated(motion_vectors(motions["line_odom"]).mean(axis=0), len(motions["GT"]))
    t, r = relative_pose_errors(np.array(constant), np.array(motions["GT"]))
    lo_t, lo_r = relative_pose_errors(np.array(motions["line_odom"]), np.array(motions["GT"]))
    print(f"{seq:4} | {' | '.join(row)} | {t.mean():8.4f} {r.mean():6.3f} | {lo_t.mean():8.4f} {lo_r.mean():6.3f}")


def print_hat(seq: str, motions: dict) -> None:
    lo_gt = differences(motions["GT"], motions["line_odom"])
    kiss_gt = differences(motions["GT"], motions["KISS-ICP"])
    lo_kiss = differences(motions["KISS-ICP"], motions["line_odom"])
    for part, cols, unit in (("t", slice(0, 3), "m"), ("r", slice(3, 6), "deg")):
        ms = [float(np.mean(np.sum(d[:, cols] ** 2, axis=1))) for d in (lo_gt, kiss_gt, lo_kiss)]
        own_lo = signed_root((ms[0] + ms[2] - ms[1]) / 2)
        own_kiss = signed_root((ms[1] + ms[2] - ms[0]) / 2)
        own_gt = signed_root((ms[0] + ms[1] - ms[2]) / 2)
        bias = ""
        if part == "r":
            bias = (f" | {' '.join(f'{v:+.4f}' for v in lo_gt[:, cols].mean(axis=0))}"
                    f" | {' '.join(f'{v:+.4f}' for v in kiss_gt[:, cols].mean(axis=0))}")
        print(f"{seq:4} {part + ' [' + unit + ']':7} | {np.sqrt(ms[0]):7.4f} {np.sqrt(ms[1]):8.4f} {np.sqrt(ms[2]):8.4f} | "
              f"{own_lo:9.4f} {own_kiss:8.4f} {own_gt:7.4f}{bias}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kitti", nargs="+", default=["00", "04", "07"])
    parser.add_argument("--no-kiss", action="store_true")
    args = parser.parse_args()
    use_kiss = not args.no_kiss and kiss_available()
    if not args.no_kiss and not use_kiss:
        print(KISS_HINT)

    print("KITTI scans aligned by each relative motion (mean over frame pairs); forward = motion along x per frame")
    head = f"{'seq':4} {'motion':10} | {'median NN [m]':>13} {'<5 cm':>6} {'<10 cm':>7} | {'forward [m]':>11}"
    print(head)
    print("-" * len(head))
    runs = []
    for seq in args.kitti:
        data = kitti_sequence(seq)
        scans = [np.ascontiguousarray(data.points(i)[:, :3], dtype=np.float64) for i in range(len(data))]
        motions = {"GT": list(data.poses)}
        odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {}))
        motions["line_odom"] = [odom.register_points(s, float(t)).pose for s, t in zip(scans, data.times)]
        if use_kiss:
            kiss = kiss_odometry(100.0)
            motions["KISS-ICP"] = []
            for s in scans:
                kiss.register_frame(s, np.zeros(len(s)))
                motions["KISS-ICP"].append(kiss.last_pose.copy())
        trees = [cKDTree(s) for s in scans]
        for name, poses in motions.items():
            rows = np.array([alignment(structure_points(scans[i - 1]), trees[i], relative(poses, i))
                             for i in range(1, len(scans))])
            forward = np.mean([relative(poses, i)[0, 3] for i in range(1, len(scans))])
            print(f"{seq:4} {name:10} | {rows[:, 0].mean():13.4f} {rows[:, 1].mean():6.3f} {rows[:, 2].mean():7.3f} | "
                  f"{forward:11.3f}")
        runs.append((seq, scans, trees, motions))

    print("\nThe same with one motion's rotation and another's translation")
    head = f"{'seq':4} {'motion':24} | {'median NN [m]':>13} {'<5 cm':>6} {'<10 cm':>7}"
    print(head)
    print("-" * len(head))
    for seq, scans, trees, motions in runs:
        print_swaps(seq, scans, trees, motions)
    print("\nThe scans' own motion: every pair registered at full resolution started at the ground truth; mean forward "
          "motion a frame (m) of the ground truth and of the registration, and the registration's RPE (mean t [m], r "
          "[deg]) against the ground truth")
    head = f"{'seq':4} {'aligner':16} | {'GT fwd':>10} {'scans fwd':>10} | {'RPE t':>8} {'r':>6}"
    print(head)
    print("-" * len(head))
    for seq, scans, _, motions in runs:
        print_scans_own_motion(seq, scans, motions, use_kiss)
    names = list(runs[0][3]) if runs else []
    print("\nEach motion's spread about its mean over the clip (rms t [m], r [deg]), and the RPE (mean t [m], r [deg]) "
          "of line_odom's mean motion repeated every frame next to line_odom's own")
    spreads = " | ".join(f"{name + ' spread':>14}" for name in names)
    head = f"{'seq':4} | {spreads} | {'constant RPE':>15} | {'line_odom RPE':>15}"
    print(head)
    print("-" * len(head))
    for seq, _, _, motions in runs:
        print_constancy(seq, motions)
    if use_kiss:
        print("\nThree-cornered hat: rms of the pairwise differences per frame, each estimate's own rms error, and the "
              "mean signed rotation error (roll pitch yaw, deg a frame) against the ground truth")
        head = (f"{'seq':4} {'':7} | {'LO-GT':>7} {'KISS-GT':>8} {'LO-KISS':>8} | {'own: LO':>9} {'KISS':>8} "
                f"{'GT':>7} | {'LO-GT mean r':>22} | {'KISS-GT mean r':>22}")
        print(head)
        print("-" * len(head))
        for seq, _, _, motions in runs:
            print_hat(seq, motions)


if __name__ == "__main__":
    main()
