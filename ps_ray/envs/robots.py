"""The Panda family. A robot is data (:class:`RobotSpec`); :class:`Panda` runs one in a :class:`Sim`.

Joint-space control as in the authors' code: an action holds 7 joint-angle deltas (x 0.05 rad),
plus a finger-width delta (x 0.2 m) when the gripper is enabled.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pybullet as p

from ps_ray.errors import UserError, choice_error

from .sim import Sim
from .urdf import locked_panda_urdf

BASES = ("panda",)
N_ARM = 7
ROBOT_STATE_DIM = N_ARM + 1  # arm joint angles, then the finger opening (0 without a gripper)
NEUTRAL = np.array([0.0, 0.41, 0.0, -1.85, 0.0, 2.26, 0.79])  # arm; fingers start closed (0, 0)
FINGER_JOINTS = (9, 10)
FORCES = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 120.0, 120.0])
FINGER_FORCE = 170.0
EE_LINK = 11  # panda_grasptarget
BASE_POSITION = (-0.6, 0.0, 0.0)
ARM_STEP = 0.05  # rad per unit action
FINGER_STEP = 0.2  # m of finger width per unit action
MAX_WIDTH = 0.08


@dataclass(frozen=True)
class RobotSpec:
    """A robot variant.

    base: the arm (only ``"panda"``).
    locked_joints: 0-based indices into the 7 arm joints (``panda_joint1`` is 0), each held exactly
        at its neutral angle; the action keeps its size and the locked elements are ignored.
    gripper: True = 8-D action with a real finger width; False = fingers closed, width reported as
        0, 7-D action; None = the task's default (pick tasks: True, reach/push: False).
    mount: where the arm stands, as the yaw in degrees of its base about the workspace centre: 0 is
        the paper's place (0.6 m behind the table centre, facing +x), 90 the side of the table
        (at -y, facing +y), 180 the far end. The same joint angles then put the end effector
        elsewhere in the world, so a policy of one mount misses its goals on another
        (docs/transfer.md).
    """

    base: str = "panda"
    locked_joints: tuple[int, ...] = ()
    gripper: bool | None = None
    mount: float = 0.0

    def __post_init__(self) -> None:
        if self.base not in BASES:
            raise choice_error("robot base", self.base, BASES, "bases")
        joints = (self.locked_joints,) if isinstance(self.locked_joints, int) else tuple(self.locked_joints)
        for j in joints:
            if isinstance(j, bool) or not isinstance(j, (int, np.integer)) or not 0 <= j < N_ARM:
                raise UserError(
                    f"bad locked joint {j!r}; valid locked joints: 0-based arm joint indices 0..{N_ARM - 1}"
                )
        object.__setattr__(self, "locked_joints", tuple(sorted({int(j) for j in joints})))
        if len(self.locked_joints) == N_ARM:
            raise UserError(
                f"bad locked joints {list(self.locked_joints)}: all {N_ARM} arm joints "
                f"locked leaves nothing to control; lock at most {N_ARM - 1}"
            )
        if self.gripper not in (None, True, False):
            raise UserError(f"bad gripper {self.gripper!r}; valid grippers: None, True, False")
        if (
            isinstance(self.mount, bool)
            or not isinstance(self.mount, (int, float))
            or not -360 <= self.mount <= 360
        ):
            raise UserError(f"bad mount {self.mount!r}; valid mounts: a yaw in degrees, -360..360")
        object.__setattr__(self, "mount", float(self.mount))

    def base_pose(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """Position and orientation (quaternion) of the arm's base for its mount."""
        yaw = math.radians(self.mount)
        x, y, z = BASE_POSITION
        position = (x * math.cos(yaw) - y * math.sin(yaw), x * math.sin(yaw) + y * math.cos(yaw), z)
        return position, (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


ROBOTS: dict[str, RobotSpec] = {
    "panda": RobotSpec(),  # R1
    "panda_l3": RobotSpec(locked_joints=(2,)),  # R2: 3rd joint locked
    "panda_l5": RobotSpec(locked_joints=(4,)),  # R3: 5th joint locked
    "panda_far": RobotSpec(mount=180.0),  # R1 at the far end of the table, facing it (transfer study)
}
_SPEC_KEYS = ("name", *(f.name for f in dataclasses.fields(RobotSpec)))


def action_dim(gripper: bool) -> int:
    """One action per arm joint, plus the finger command with a working gripper."""
    return N_ARM + int(gripper)


def resolve_robot(robot: str | RobotSpec | Mapping) -> RobotSpec:
    """A built-in name, a :class:`RobotSpec`, or a mapping of its fields (plus an optional ``name``
    of a built-in to start from), e.g. ``{"base": "panda", "locked_joints": [1]}``."""
    if isinstance(robot, RobotSpec):
        return robot
    if isinstance(robot, str):
        if robot not in ROBOTS:
            raise choice_error("robot", robot, ROBOTS)
        return ROBOTS[robot]
    if isinstance(robot, Mapping):
        fields = dict(robot)
        for key in fields:
            if key not in _SPEC_KEYS:
                raise choice_error("robot key", key, _SPEC_KEYS)
        start = resolve_robot(fields.pop("name")) if "name" in fields else RobotSpec()
        return dataclasses.replace(start, **fields)
    raise UserError(f"unknown robot {robot!r}; valid robots: {', '.join(ROBOTS)}, a RobotSpec or a mapping")


class Panda:
    """A Panda in a :class:`Sim`: locked joints are ``fixed`` in a generated URDF."""

    def __init__(self, sim: Sim, spec: RobotSpec, gripper: bool) -> None:
        self.sim, self.spec, self.gripper = sim, spec, gripper
        self.action_dim = action_dim(gripper)
        urdf = locked_panda_urdf({j: float(NEUTRAL[j]) for j in spec.locked_joints})
        self.body = sim.load_urdf(urdf, *spec.base_pose())
        cid = sim.client
        for finger in FINGER_JOINTS:
            p.changeDynamics(
                self.body, finger, lateralFriction=1.0, spinningFriction=0.001, physicsClientId=cid
            )
        self.free = np.array([j for j in range(N_ARM) if j not in spec.locked_joints])
        self.joints = [*self.free.tolist(), *FINGER_JOINTS]  # every movable joint, in control order
        self.forces = [*FORCES[self.free].tolist(), FINGER_FORCE, FINGER_FORCE]
        self.neutral = [*NEUTRAL[self.free].tolist(), 0.0, 0.0]
        self._free = self.free.tolist()
        self.target = list(self.neutral)
        self._state = np.zeros(ROBOT_STATE_DIM)
        self._state[:N_ARM] = NEUTRAL  # locked angles stay here

    def reset(self) -> None:
        """Neutral pose, zero velocities, motors holding it."""
        cid = self.sim.client
        for joint, angle in zip(self.joints, self.neutral):
            p.resetJointState(self.body, joint, angle, 0.0, physicsClientId=cid)
        p.setJointMotorControlArray(
            self.body,
            self.joints,
            p.POSITION_CONTROL,
            targetPositions=self.neutral,
            forces=self.forces,
            physicsClientId=cid,
        )

    def _positions(self) -> list[float]:
        return [s[0] for s in p.getJointStates(self.body, self.joints, physicsClientId=self.sim.client)]

    def state(self) -> np.ndarray:
        """7 arm joint angles (locked ones at their lock angle) + finger width (0 when blocked)."""
        q = self._positions()
        n = len(self._free)
        self._state[self.free] = q[:n]
        self._state[N_ARM] = q[n] + q[n + 1] if self.gripper else 0.0
        return self._state.copy()

    def set_action(self, action: np.ndarray) -> None:
        """Send position targets: current angle + 0.05 * action (clipped to [-1, 1])."""
        a = np.clip(action, -1.0, 1.0).tolist()  # plain floats: faster than numpy for 9 values
        q = self._positions()
        n = len(self._free)
        target = [q[k] + ARM_STEP * a[j] for k, j in enumerate(self._free)]
        width = min(max(q[n] + q[n + 1] + FINGER_STEP * a[N_ARM], 0.0), MAX_WIDTH) if self.gripper else 0.0
        target += (0.5 * width, 0.5 * width)
        self.target = target  # the last motor targets (movable joints, control order)
        p.setJointMotorControlArray(
            self.body,
            self.joints,
            p.POSITION_CONTROL,
            targetPositions=target,
            forces=self.forces,
            physicsClientId=self.sim.client,
        )

    def action_toward(self, point: np.ndarray) -> np.ndarray:
        """The action that moves the end effector toward a world point: each free joint's step to
        PyBullet's inverse-kinematics solution from the current pose, clipped to [-1, 1]; the
        fingers hold. Reading the pose and solving move nothing."""
        solution = p.calculateInverseKinematics(
            self.body,
            EE_LINK,
            [float(x) for x in point],
            maxNumIterations=50,
            physicsClientId=self.sim.client,
        )
        now = self._positions()
        action = np.zeros(self.action_dim)
        n = len(self._free)  # IK answers every movable joint in control order: free arm joints first
        action[:n] = (np.asarray(solution[:n]) - np.asarray(now[:n])) / ARM_STEP
        return np.clip(action, -1.0, 1.0)

    def ee_position(self) -> np.ndarray:
        return np.array(
            p.getLinkState(
                self.body, EE_LINK, computeForwardKinematics=True, physicsClientId=self.sim.client
            )[4]
        )


def arm(robot: str | Mapping) -> tuple[str, tuple[int, ...], float]:
    """The arm a robot is: base model, locked joints and mount (a gripper does not make another
    arm; the same arm mounted elsewhere moves differently, so it does)."""
    spec = resolve_robot(robot)
    return spec.base, spec.locked_joints, spec.mount
