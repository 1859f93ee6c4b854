"""The sensor's mounting from static TF: the transform base_frame -> the scan's header.frame_id, as a robot's URDF
(robot_state_publisher) or a static_transform_publisher puts it on /tf_static.

tf2_ros and tf2_py are not published as wheels for this ROS (docs/DESIGN.md §4), so the tree of static transforms is kept
here: every child frame has one parent (REP-105), and a lookup walks both frames up to their common ancestor.
"""
from __future__ import annotations

import math

import numpy as np

from line_odom import convert, frames


class TransformError(convert.ConversionError):
    def __init__(self, field: str, reason: str):
        super().__init__("TFMessage", field, reason)


def transform_to_matrix(transform, field: str) -> np.ndarray:
    """geometry_msgs/Transform -> 4x4; TransformError naming `field` for a non-finite translation or a rotation that
    is not a unit quaternion."""
    t, q = transform.translation, transform.rotation
    translation = np.array([t.x, t.y, t.z], dtype=float)
    quat = np.array([q.x, q.y, q.z, q.w], dtype=float)
    if not np.isfinite(translation).all():
        raise TransformError(f"{field}.translation", f"expected finite values, got {translation.tolist()}")
    norm = float(np.linalg.norm(quat))
    if not math.isfinite(norm) or abs(norm - 1.0) > 1e-3:
        raise TransformError(f"{field}.rotation", f"expected a unit quaternion, got {quat.tolist()} (norm {norm:g})")
    return frames.pose_from_params([*translation, *(quat / norm)], field)


class StaticTransforms:
    """Static transforms by child frame: T_parent_child and the parent."""

    def __init__(self):
        self._parents: dict[str, tuple[str, np.ndarray]] = {}

    def __len__(self) -> int:
        return len(self._parents)

    def add(self, msg) -> int:
        """Every transform of a tf2_msgs/TFMessage (a later one for the same child replaces it); returns how many
        were kept. TransformError naming the field for an unusable one (the message's others are still kept)."""
        kept, error = 0, None
        for i, stamped in enumerate(msg.transforms):
            field = f"transforms[{i}]"
            parent = str(stamped.header.frame_id).lstrip("/")
            child = str(stamped.child_frame_id).lstrip("/")
            try:
                if not parent or not child:
                    raise TransformError(f"{field}.header.frame_id" if not parent else f"{field}.child_frame_id",
                                         "expected a frame name, got an empty string")
                if parent == child or self._is_ancestor(child, of=parent):
                    raise TransformError(f"{field}.child_frame_id", f"{child!r} under {parent!r} would close a loop "
                                                                    "in the TF tree")
                self._parents[child] = (parent, transform_to_matrix(stamped.transform, f"{field}.transform"))
                kept += 1
            except TransformError as err:
                error = error or err
        if error is not None:
            raise error
        return kept

    def _is_ancestor(self, frame: str, *, of: str) -> bool:
        node = of
        while node in self._parents:
            node = self._parents[node][0]
            if node == frame:
                return True
        return False

    def _chain(self, frame: str) -> dict[str, np.ndarray]:
        """T_ancestor_frame for the frame itself and each of its ancestors."""
        chain = {frame: np.eye(4)}
        T = np.eye(4)
        while frame in self._parents:
            frame, T_parent_child = self._parents[frame]
            T = T_parent_child @ T
            chain[frame] = T
        return chain

    def lookup(self, target: str, source: str) -> np.ndarray | None:
        """T_target_source (maps source-frame coordinates into target), or None while the two frames are not
        connected."""
        target, source = target.lstrip("/"), source.lstrip("/")
        up_from_source = self._chain(source)
        up_from_target = self._chain(target)
        for ancestor, T_ancestor_target in up_from_target.items():
            if ancestor in up_from_source:
                return frames.inverse(T_ancestor_target) @ up_from_source[ancestor]
        return None
