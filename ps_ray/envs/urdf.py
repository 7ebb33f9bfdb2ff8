"""Generated URDFs (locked-joint Pandas, bundles of static boxes), cached on disk by content hash."""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pybullet_data

PANDA_URDF = os.path.join(pybullet_data.getDataPath(), "franka_panda", "panda.urdf")
CACHE_DIR = Path(tempfile.gettempdir()) / "ps_ray_urdf"


def cached_urdf(text: str, stem: str) -> str:
    """Write ``text`` once to ``CACHE_DIR/<stem>-<hash>.urdf`` (atomic, safe across processes)."""
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    path = CACHE_DIR / f"{stem}-{digest}.urdf"
    if not path.exists():  # a whole file or none: written beside it, then renamed over it (the
        # envs package stays free of ps_ray's store, as it is of torch and Ray; a cache in the
        # temp folder needs no fsync)
        CACHE_DIR.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=CACHE_DIR, suffix=".part", delete=False) as part:
            part.write(text)
        os.replace(part.name, path)
    return str(path)


def _rpy_to_matrix(r: float, p: float, y: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _matrix_to_rpy(m: np.ndarray) -> tuple[float, float, float]:
    return (
        math.atan2(m[2, 1], m[2, 2]),
        math.asin(-max(-1.0, min(1.0, m[2, 0]))),
        math.atan2(m[1, 0], m[0, 0]),
    )


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    x, y, z = axis / np.linalg.norm(axis)
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def locked_panda_urdf(locks: Mapping[int, float]) -> str:
    """Panda URDF whose arm joints ``{index: angle}`` (0-based) are ``type="fixed"`` at ``angle``.

    The lock rotation is folded into the joint origin, so the kinematics equal the free robot's at
    that angle; joint indices in PyBullet are unchanged (fixed joints still count).
    """
    if not locks:
        return PANDA_URDF
    tree = ET.parse(PANDA_URDF)
    mesh_dir = os.path.dirname(PANDA_URDF) + "/"
    for mesh in tree.iter("mesh"):  # absolute mesh paths: the generated file lives elsewhere
        mesh.set("filename", mesh.get("filename", "").replace("package://", mesh_dir))
    joints = {j.get("name"): j for j in tree.iter("joint")}
    for index, angle in sorted(locks.items()):
        joint = joints[f"panda_joint{index + 1}"]
        origin = joint.find("origin")
        axis = np.array([float(v) for v in joint.find("axis").get("xyz").split()])
        rpy = [float(v) for v in origin.get("rpy", "0 0 0").split()]
        rotation = _rpy_to_matrix(*rpy) @ _axis_rotation(axis, angle)
        origin.set("rpy", " ".join(repr(v) for v in _matrix_to_rpy(rotation)))
        joint.set("type", "fixed")
        for tag in ("axis", "limit", "dynamics", "safety_controller"):
            for child in joint.findall(tag):
                joint.remove(child)
    text = ET.tostring(tree.getroot(), encoding="unicode")
    return cached_urdf('<?xml version="1.0"?>\n' + text + "\n", "panda_locked")


def boxes_urdf(name: str, boxes: np.ndarray, rgba: tuple[float, ...]) -> str:
    """One static link holding many boxes; ``boxes`` rows are (x, y, z, half_x, half_y, half_z)."""
    color = " ".join(f"{c:g}" for c in rgba)
    lines = [
        '<?xml version="1.0"?>',
        f'<robot name="{name}">',
        f'  <link name="{name}">',
        '    <inertial><mass value="0"/>'
        '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>',
    ]
    for x, y, z, hx, hy, hz in np.asarray(boxes, dtype=float).tolist():
        box = f'<box size="{2 * hx!r} {2 * hy!r} {2 * hz!r}"/>'
        geometry = f'<origin xyz="{x!r} {y!r} {z!r}"/><geometry>{box}</geometry>'
        lines.append(f'    <visual>{geometry}<material name="c"><color rgba="{color}"/></material></visual>')
        lines.append(f"    <collision>{geometry}</collision>")
    lines += ["  </link>", "</robot>", ""]
    return cached_urdf("\n".join(lines), name)
