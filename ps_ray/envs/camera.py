"""Headless camera: PyBullet's TinyRenderer, matrices computed once."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pybullet as p


@dataclass(frozen=True)
class Camera:
    width: int = 480
    height: int = 360
    target: tuple[float, float, float] = (-0.3, 0.0, 0.2)
    distance: float = 1.6
    yaw: float = 45.0
    pitch: float = -30.0
    fov: float = 45.0
    _matrices: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        view = p.computeViewMatrixFromYawPitchRoll(self.target, self.distance, self.yaw, self.pitch, 0.0, 2)
        proj = p.computeProjectionMatrixFOV(self.fov, self.width / self.height, 0.1, 10.0)
        object.__setattr__(self, "_matrices", (view, proj))

    def frame(self, client: int) -> np.ndarray:
        """An RGB frame, ``(height, width, 3)`` uint8."""
        view, proj = self._matrices
        _, _, rgba, _, _ = p.getCameraImage(
            self.width, self.height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=client
        )
        return np.asarray(rgba, dtype=np.uint8).reshape(self.height, self.width, 4)[..., :3].copy()
