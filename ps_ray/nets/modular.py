"""Modular SAC networks: task module g (task input -> latent) + robot module f (latent + robot -> out).

Every method is a :class:`ps_ray.specs.methods.MethodSpec`; one :class:`TaskModule` and one
robot-module trunk are configured from a :class:`MethodSpec` and :class:`NetDims`.
Architecture (hidden = 256, latent D):

- modular task module:  RunningNorm(task) -> mlp(task, [h, h], D) [-> cosine vs K = D anchors (PS)]
- actor robot module:   RunningNorm(robot) -> Linear(robot, h/2) + ReLU, concat latent
                        -> mlp(D + h/2, [h, h], 2A) -> (mean, log_std clamped to [-9, 2])
- critic robot module:  [action, RunningNorm(robot)] -> Linear(A + robot, h/2) + ReLU, concat latent
                        -> mlp(D + h/2, [h, h], 1) -> q (B,)
- plain: one MLP over the whole state cut in the middle. Bottom ("task module"):
  RunningNorm(task + robot), then [+ action for the critic, unnormalised]
  -> mlp(in, [h], h, out_act=True); top ("robot module"): mlp(h, [h], heads). Latent width = h.
- devin / devin_large: Dropout(0.25) on the latent at the robot module's input (where the authors'
  commented-out Dropout sits), so ``interface()`` returns the undropped latent.
"""

from __future__ import annotations

import dataclasses
from typing import TypeVar

import torch
from torch import Tensor, nn

from ps_ray.errors import UserError
from ps_ray.nets.mlp import mlp
from ps_ray.nets.normalize import RunningNorm
from ps_ray.nets.relative import RelativeProjection
from ps_ray.specs.defaults import HIDDEN, INTERFACE_DIM
from ps_ray.specs.dims import NetDims
from ps_ray.specs.methods import MethodSpec, RelativeSpec, method_spec

LOG_STD_MIN, LOG_STD_MAX = -9.0, 2.0


class TaskModule(nn.Module):
    """g_k: task input -> latent (B x D). For plain it is the bottom half and also sees robot_in
    (and, in a critic, the action)."""

    def __init__(
        self,
        spec: MethodSpec,
        dims: NetDims,
        latent_dim: int,
        hidden: int = HIDDEN,
        *,
        relative: RelativeProjection | None = None,
        sees_action: bool = False,
    ) -> None:
        super().__init__()
        if sees_action and spec.modular:
            raise ValueError("only the plain bottom half sees the action; modular task modules do not")
        self.spec, self.dims, self.latent_dim, self.sees_action = spec, dims, latent_dim, sees_action
        if spec.modular:
            self.norm = RunningNorm(dims.task_dim)
            self.body = mlp(dims.task_dim, [hidden, hidden], latent_dim)
        else:
            self.norm = RunningNorm(dims.task_dim + dims.robot_dim)
            in_dim = dims.task_dim + dims.robot_dim + (dims.action_dim if sees_action else 0)
            self.body = mlp(in_dim, [hidden], latent_dim, out_act=True)
        self.relative = relative
        if relative is not None and spec.defer_relative:
            # off while training: the raw latent is the interface until consolidation switches it
            # the switch travels in the state dict; a Python mirror keeps forward from reading a
            # device tensor (a host sync per pass on a GPU)
            self.register_buffer("relative_on", torch.tensor(False))
        self._relative_on = not (relative is not None and spec.defer_relative)

    @property
    def anchors(self) -> Tensor | None:
        return None if self.relative is None else self.relative.anchors

    @property
    def projection(self) -> RelativeProjection | None:
        """The relative projection in use at the cut: None for a raw latent, which is also a
        deferred projection's (MethodSpec.defer_relative) until :meth:`switch_relative_on`."""
        if self.relative is None or not self._relative_on:
            return None
        return self.relative

    @property
    def projection_off(self) -> bool:
        """Whether a deferred relative projection is not yet switched on (the cut is raw)."""
        return self.relative is not None and self.projection is None

    def switch_relative_on(self) -> None:
        """Make a deferred relative projection the interface (consolidation does, then distils)."""
        if not hasattr(self, "relative_on"):
            raise ValueError(f"method {self.spec.name!r} has no deferred relative projection")
        self.relative_on.fill_(True)
        self._relative_on = True

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        if prefix + "relative_on" in state_dict:
            self._relative_on = bool(state_dict[prefix + "relative_on"])

    def encode(self, task_in: Tensor) -> Tensor:
        """Normalised input -> raw latent (modular methods; also embeds the PS anchors)."""
        return self.body(self.norm(task_in))

    def forward(
        self, task_in: Tensor, robot_in: Tensor | None = None, action: Tensor | None = None
    ) -> Tensor:
        if self.spec.modular:
            projection = self.projection
            return self.encode(task_in) if projection is None else projection(self.encode, task_in)
        if robot_in is None or (self.sees_action and action is None):
            needs = "robot_in and action" if self.sees_action else "robot_in"
            raise ValueError(f"the plain bottom half needs {needs}")
        x = self.norm(torch.cat([task_in, robot_in], -1))
        if self.sees_action:
            x = torch.cat([x, action], -1)
        return self.body(x)

    def update_norm(self, task_in: Tensor, robot_in: Tensor) -> None:
        self.norm.update(task_in if self.spec.modular else torch.cat([task_in, robot_in], -1))

    def penalized(
        self, task_in: Tensor, robot_in: Tensor | None = None, action: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """The latent and the relative projection's penalties (RelativeSpec.norm_reg, ref_weight;
        zero for other methods), from one pass of the encoder."""
        projection = self.projection
        if projection is None:
            return self(task_in, robot_in, action), task_in.new_zeros(())
        return projection.penalized(self.encode, task_in)

    def penalty(self, task_in: Tensor) -> Tensor:
        """The relative projection's penalties alone (see :meth:`penalized`)."""
        return self.penalized(task_in)[1]


def _relative_projection(
    spec: MethodSpec,
    relative: RelativeSpec | None,
    dims: NetDims,
    latent_dim: int,
    anchors: Tensor | None,
    anchor_grad: bool | None,
) -> RelativeProjection | None:
    if relative is None:
        return None  # anchors, if given, mean nothing to a raw-latent cut
    expected = (latent_dim, dims.task_dim)
    if anchors is None:
        hint = "(K = interface dim, task_dim)"
        raise UserError(f"method {spec.name!r} needs anchors of shape {expected} {hint}")
    if tuple(anchors.shape) != expected:
        raise UserError(
            f"method {spec.name!r}: anchors have shape {tuple(anchors.shape)}, expected {expected} "
            f"(K = interface dim {latent_dim}, task_dim {dims.task_dim})"
        )
    if anchor_grad is not None:
        relative = dataclasses.replace(relative, anchor_grad=anchor_grad)
    return RelativeProjection(anchors, relative)


class _RobotModule(nn.Module):
    """Shared trunk of f_r: features from the latent and (modular only) the robot state [+ action]."""

    def __init__(
        self, spec: MethodSpec, dims: NetDims, latent_dim: int, hidden: int, out_dim: int, takes_action: bool
    ) -> None:
        super().__init__()
        self.spec, self.dims, self.latent_dim, self.takes_action = spec, dims, latent_dim, takes_action
        self.latent_dropout = nn.Dropout(spec.dropout) if spec.dropout > 0 else nn.Identity()
        if spec.modular:
            robot_width = hidden // 2
            self.norm: RunningNorm | None = RunningNorm(dims.robot_dim)
            in_dim = dims.robot_dim + (dims.action_dim if takes_action else 0)
            self.embed: nn.Module | None = nn.Sequential(nn.Linear(in_dim, robot_width), nn.ReLU())
            self.head = mlp(latent_dim + robot_width, [hidden, hidden], out_dim)
        else:
            self.norm = self.embed = None  # plain top half: sees only the latent
            self.head = mlp(latent_dim, [hidden], out_dim)

    def trunk(self, latent: Tensor, robot_in: Tensor, action: Tensor | None = None) -> Tensor:
        latent = self.latent_dropout(latent)
        if self.embed is None:
            return self.head(latent)
        robot = self.norm(robot_in)
        if self.takes_action:
            robot = torch.cat([action, robot], -1)  # actions are already in [-1, 1]
        return self.head(torch.cat([latent, self.embed(robot)], -1))

    def update_norm(self, task_in: Tensor, robot_in: Tensor) -> None:
        if self.norm is not None:
            self.norm.update(robot_in)


class ActorRobotModule(_RobotModule):
    def __init__(self, spec: MethodSpec, dims: NetDims, latent_dim: int, hidden: int = HIDDEN) -> None:
        super().__init__(spec, dims, latent_dim, hidden, 2 * dims.action_dim, takes_action=False)

    def forward(self, latent: Tensor, robot_in: Tensor) -> tuple[Tensor, Tensor]:
        mean, log_std = self.trunk(latent, robot_in).chunk(2, dim=-1)
        return mean, log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)


class CriticRobotModule(_RobotModule):
    def __init__(self, spec: MethodSpec, dims: NetDims, latent_dim: int, hidden: int = HIDDEN) -> None:
        super().__init__(spec, dims, latent_dim, hidden, 1, takes_action=True)

    def forward(self, latent: Tensor, robot_in: Tensor, action: Tensor) -> Tensor:
        return self.trunk(latent, robot_in, action).squeeze(-1)


class _Modular(nn.Module):
    """A task module and a robot module of the same method, latent width and dims."""

    robot_type: type[_RobotModule]

    def __init__(self, task: TaskModule, robot: _RobotModule, translate: nn.Module | None = None) -> None:
        super().__init__()
        if not isinstance(robot, self.robot_type):
            wanted, got = self.robot_type.__name__, type(robot).__name__
            raise ValueError(f"{type(self).__name__} needs a {wanted}, got {got}")
        _check_compatible(task, robot)
        self.task, self.robot = task, robot
        self.translate = translate  # a stitched policy's fitted latent translation, if any

    def to_robot(self, latent: Tensor) -> Tensor:
        """The task module's latent as the robot module takes it (translated, if stitched so)."""
        return latent if self.translate is None else self.translate(latent)

    @property
    def spec(self) -> MethodSpec:
        return self.task.spec

    @property
    def dims(self) -> NetDims:
        return self.task.dims

    @property
    def latent_dim(self) -> int:
        return self.task.latent_dim

    @property
    def anchors(self) -> Tensor | None:
        return self.task.anchors


class Actor(_Modular):
    robot_type = ActorRobotModule

    def forward(self, task_in: Tensor, robot_in: Tensor) -> tuple[Tensor, Tensor]:
        """Pre-tanh Gaussian (mean, log_std)."""
        return self.robot(self.to_robot(self.task(task_in, robot_in)), robot_in)

    def interface(self, task_in: Tensor, robot_in: Tensor) -> Tensor:
        """The latent at the cut (the relative vector for PS)."""
        return self.task(task_in, robot_in)

    def penalized(self, task_in: Tensor, robot_in: Tensor) -> tuple[tuple[Tensor, Tensor], Tensor]:
        """``forward`` and the task module's penalties, from one pass of the task module."""
        latent, penalty = self.task.penalized(task_in, robot_in)
        return self.robot(self.to_robot(latent), robot_in), penalty


class Critic(_Modular):
    robot_type = CriticRobotModule

    def forward(self, task_in: Tensor, robot_in: Tensor, action: Tensor) -> Tensor:
        return self.robot(self.to_robot(self.task(task_in, robot_in, action)), robot_in, action)

    def interface(self, task_in: Tensor, robot_in: Tensor, action: Tensor) -> Tensor:
        return self.task(task_in, robot_in, action)

    def penalized(self, task_in: Tensor, robot_in: Tensor, action: Tensor) -> tuple[Tensor, Tensor]:
        """``forward`` and the task module's penalties, from one pass of the task module."""
        latent, penalty = self.task.penalized(task_in, robot_in, action)
        return self.robot(self.to_robot(latent), robot_in, action), penalty


def _check_compatible(task: TaskModule, robot: _RobotModule) -> None:
    problems = [
        f"{what} differs (task side {a!r}, robot side {b!r})"
        for what, a, b in (
            ("method", task.spec.name, robot.spec.name),
            ("latent width", task.latent_dim, robot.latent_dim),
            ("dims", task.dims, robot.dims),
        )
        if a != b
    ]
    if task.sees_action != (robot.takes_action and not task.spec.modular):
        problems.append("actor/critic role differs")
    if problems:
        raise UserError("cannot combine task module and robot module: " + "; ".join(problems))


Net = TypeVar("Net", Actor, Critic)


def _build(
    net_type: type[Net],
    method: str | MethodSpec,
    dims: NetDims,
    *,
    interface_dim: int = INTERFACE_DIM,
    hidden: int = HIDDEN,
    anchors: Tensor | None = None,
    anchor_grad: bool | None = None,
) -> Net:
    """The one builder: an Actor or a Critic of ``method`` (a key or resolved settings)."""
    spec = method_spec(method)
    critic = net_type is Critic
    latent_dim = spec.latent_dim(interface_dim, hidden)
    relative = _relative_projection(spec, spec.relative_for(critic), dims, latent_dim, anchors, anchor_grad)
    sees_action = critic and not spec.modular
    task = TaskModule(spec, dims, latent_dim, hidden, relative=relative, sees_action=sees_action)
    robot_type = CriticRobotModule if critic else ActorRobotModule
    return net_type(task, robot_type(spec, dims, latent_dim, hidden))


def build_actor(method: str | MethodSpec, dims: NetDims, **options) -> Actor:
    """Options: interface_dim (128), hidden (256), anchors (PS), anchor_grad (None: the method's)."""
    return _build(Actor, method, dims, **options)


def build_critic(method: str | MethodSpec, dims: NetDims, **options) -> Critic:
    """Options as for :func:`build_actor`."""
    return _build(Critic, method, dims, **options)


@torch.no_grad()
def update_normalizers(module: nn.Module, task_in: Tensor, robot_in: Tensor) -> None:
    """Update every RunningNorm inside ``module`` (any container of actors/critics, targets
    included): task norms get task_in (plain: concat(task_in, robot_in)), robot norms robot_in."""
    for sub in module.modules():
        if isinstance(sub, (TaskModule, _RobotModule)):
            sub.update_norm(task_in, robot_in)


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
