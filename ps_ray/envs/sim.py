"""One headless PyBullet client: physics settings, stepping, body creation and queries."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pybullet as p

TIMESTEP = 1.0 / 500.0
SUBSTEPS = 20  # simulation steps per env step: dt = 0.04 s
GRAVITY = -9.81

Vec = Sequence[float]


class Sim:
    """Owns one PyBullet client in DIRECT mode; creates bodies from cached shapes.

    Determinism: PyBullet keeps a contact cache (warm-started impulses) per body pair, so an object
    put back in place on the table carries the last episode's contacts into the next one and a
    replay diverges. Tasks therefore remove and re-create their moving bodies at each reset (cheap
    with cached shapes, and it leaks nothing, unlike re-loading URDFs). Static bodies stay: the
    robot's contacts with them vanish when it is put back in its neutral pose, and PyBullet sorts
    overlapping pairs deterministically. The tests replay seeds in used and fresh envs bit for bit.
    """

    def __init__(
        self, timestep: float = TIMESTEP, substeps: int = SUBSTEPS, gravity: float = GRAVITY
    ) -> None:
        self.client: int | None = p.connect(p.DIRECT)
        self.substeps = substeps
        self.dt = timestep * substeps
        p.setTimeStep(timestep, physicsClientId=self.client)
        p.setGravity(0.0, 0.0, gravity, physicsClientId=self.client)
        self._shapes: dict[tuple, int] = {}

    # -- stepping ---------------------------------------------------------------------------
    def step(self) -> None:
        step, cid = p.stepSimulation, self.client
        for _ in range(self.substeps):
            step(physicsClientId=cid)

    # -- bodies -----------------------------------------------------------------------------
    def _shape(self, visual: bool, geom: int, size: tuple[float, ...], rgba: tuple[float, ...] = ()) -> int:
        key = (visual, geom, size, rgba)
        if key not in self._shapes:
            dims = {"halfExtents": size} if geom == p.GEOM_BOX else {"radius": size[0]}
            if visual:
                self._shapes[key] = p.createVisualShape(
                    geom, rgbaColor=rgba, physicsClientId=self.client, **dims
                )
            else:
                self._shapes[key] = p.createCollisionShape(geom, physicsClientId=self.client, **dims)
        return self._shapes[key]

    def add_shape(
        self,
        geom: int,
        size: Vec,
        position: Vec,
        *,
        rgba: Vec = (0.8, 0.8, 0.8, 1.0),
        mass: float = 0.0,
        ghost: bool = False,
        lateral_friction: float | None = None,
    ) -> int:
        """A box (``size`` = half extents) or sphere (``size`` = (radius,)); ``ghost``: visual only."""
        size_t = tuple(float(s) for s in size)
        rgba_t = tuple(float(c) for c in rgba)
        body = p.createMultiBody(
            baseMass=mass,
            baseCollisionShapeIndex=-1 if ghost else self._shape(False, geom, size_t),
            baseVisualShapeIndex=self._shape(True, geom, size_t, rgba_t),
            basePosition=[float(v) for v in position],
            physicsClientId=self.client,
        )
        if lateral_friction is not None:
            p.changeDynamics(body, -1, lateralFriction=lateral_friction, physicsClientId=self.client)
        return body

    def add_box(self, half_extents: Vec, position: Vec, **kwargs) -> int:
        return self.add_shape(p.GEOM_BOX, half_extents, position, **kwargs)

    def load_urdf(
        self, path: str, position: Vec = (0.0, 0.0, 0.0), orientation: Vec = (0.0, 0.0, 0.0, 1.0)
    ) -> int:
        """Load a fixed-base URDF (once per env: PyBullet does not free a removed URDF's memory)."""
        return p.loadURDF(
            path,
            basePosition=list(position),
            baseOrientation=list(orientation),
            useFixedBase=True,
            physicsClientId=self.client,
        )

    def remove(self, body: int) -> None:
        p.removeBody(body, physicsClientId=self.client)

    def move(self, body: int, position: Vec) -> None:
        """Teleport a body without collisions (a goal marker)."""
        p.resetBasePositionAndOrientation(
            body, [float(v) for v in position], (0.0, 0.0, 0.0, 1.0), physicsClientId=self.client
        )

    def set_base_state(self, body: int, state: np.ndarray) -> None:
        """Put a base where :meth:`base_state` says: position, Euler angles and both velocities."""
        position, euler, linear, angular = (tuple(map(float, state[i : i + 3])) for i in (0, 3, 6, 9))
        quaternion = p.getQuaternionFromEuler(euler)
        p.resetBasePositionAndOrientation(body, position, quaternion, physicsClientId=self.client)
        p.resetBaseVelocity(body, linear, angular, physicsClientId=self.client)

    # -- queries ----------------------------------------------------------------------------
    def base_state(self, body: int) -> np.ndarray:
        """Position (3), Euler angles (3), linear velocity (3), angular velocity (3) of a base."""
        pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
        lin, ang = p.getBaseVelocity(body, physicsClientId=self.client)
        return np.array((*pos, *p.getEulerFromQuaternion(quat), *lin, *ang))

    def in_contact(self, body_a: int, body_b: int) -> bool:
        return bool(p.getContactPoints(body_a, body_b, physicsClientId=self.client))

    def detect_collisions(self) -> None:
        """Refresh contact points without stepping (used after a reset)."""
        p.performCollisionDetection(physicsClientId=self.client)

    def close(self) -> None:
        client, self.client = self.client, None
        if client is not None:
            try:
                p.disconnect(physicsClientId=client)
            except Exception:  # already gone (e.g. at interpreter shutdown)
                pass

    def __del__(self) -> None:
        self.close()
