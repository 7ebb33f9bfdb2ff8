"""Trainer speed: the RLlib path against a bare-torch loop doing the same work, in one run.

Both sides step the same envs (num_envs in lockstep), act with the same actor, write whole
episodes into the same HindsightReplay, and run the same SAC update (`sac_forward` + `sac_losses`,
Adam, Polyak) with the same nets, batch size and updates per env step. The last line is
`ratio <rllib / bare-torch>` of env steps per second.
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import torch

from ps_ray.cli.args import Parser
from ps_ray.data.her import HindsightReplay
from ps_ray.nets.modular import update_normalizers
from ps_ray.nets.obs import dims_from_spaces, split_obs
from ps_ray.nets.sac import SACHyper, build_sac_nets, polyak, sac_forward, sac_losses, squashed_sample
from ps_ray.rllib.episodes import train_batch
from ps_ray.rllib.loop import make_env
from ps_ray.specs.train import TrainSpec


class BareTrainer:
    """The same data flow as ModularSAC.training_step, in plain torch + numpy."""

    def __init__(self, spec: TrainSpec, anchors: np.ndarray | None = None):
        self.spec = spec
        self.envs = [make_env(spec) for _ in range(spec.num_envs)]
        env = self.envs[0]
        self.dims = dims_from_spaces(env.observation_space, env.action_space)
        self.nets = build_sac_nets(
            spec.method, self.dims, interface_dim=spec.interface_dim, hidden=spec.hidden, anchors=anchors
        )
        self.log_alpha = torch.full((1,), float(np.log(spec.initial_alpha)), requires_grad=True)
        params = [
            *self.nets.actor.parameters(),
            *self.nets.critic.parameters(),
            *self.nets.critic_twin.parameters(),
            self.log_alpha,
        ]
        self.optimizer = torch.optim.Adam(params, lr=spec.lr)
        self.hp = SACHyper(gamma=spec.gamma, action_l2=spec.action_l2)
        self.replay = HindsightReplay(
            {k: (s.shape, np.float32) for k, s in env.observation_space.spaces.items()},
            action_dim=self.dims.action_dim,
            horizon=env.max_episode_steps,
            capacity_episodes=2_000,
            reward_fn=lambda a, d: env.compute_reward(a, d, None),
            seed=spec.seed,
        )
        self.env_steps = self.updates = self.episodes = 0

    def _rollout(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        seeds = [self.spec.seed * 1000 + self.episodes + i for i in range(len(self.envs))]
        first = [env.reset(seed=s)[0] for env, s in zip(self.envs, seeds)]
        obs = [{k: [o[k]] for k in o} for o in first]
        actions = [[] for _ in self.envs]
        current = first
        for _ in range(self.envs[0].max_episode_steps):
            batch = {k: np.stack([o[k] for o in current]) for k in current[0]}
            with torch.no_grad():
                act, _ = squashed_sample(*self.nets.actor(*split_obs(batch)))
            act = act.numpy()
            current = [env.step(a)[0] for env, a in zip(self.envs, act)]
            for i, o in enumerate(current):
                actions[i].append(act[i])
                for k in o:
                    obs[i][k].append(o[k])
        self.episodes += len(self.envs)
        return (
            {k: np.stack([np.stack(o[k]) for o in obs]) for k in obs[0]},
            np.stack([np.stack(a) for a in actions]),
        )

    def step(self) -> None:
        spec = self.spec
        for _ in range(max(1, spec.episodes_per_step // len(self.envs))):
            obs, actions = self._rollout()
            self.replay.add_episodes(obs, actions)
            steps = actions.shape[0] * actions.shape[1]
            self.env_steps += steps
            seen = self.replay.relabelled(obs) if self.nets.actor.spec.hindsight_norm else obs
            task_in, robot_in = split_obs(seen)
            update_normalizers(self.nets, task_in, robot_in)
            n_updates = max(1, round(steps * spec.updates_per_step))
            batch = train_batch(self.replay.sample_many(n_updates, spec.batch_size))
            for i in range(n_updates):
                part = {k: v[i * spec.batch_size : (i + 1) * spec.batch_size] for k, v in batch.items()}
                losses = sac_losses(
                    sac_forward(self.nets, part),
                    part["rewards"],
                    self.log_alpha,
                    self.hp,
                    self.dims.action_dim,
                )
                self.optimizer.zero_grad(set_to_none=True)
                losses["total"].backward()
                self.optimizer.step()
                polyak(self.nets, spec.tau)
            self.updates += n_updates


def _measure(step, counters, seconds: float) -> tuple[float, float]:
    steps0, updates0 = counters()
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        step()
    elapsed = time.perf_counter() - start
    steps1, updates1 = counters()
    return (steps1 - steps0) / elapsed, (updates1 - updates0) / elapsed


def run(spec: TrainSpec, seconds: float = 60.0, rounds: int = 2, compile: bool = False) -> dict[str, float]:
    """Alternate RLlib and bare measurements (after a warm-up that fills the buffer); with
    ``compile``, also RLlib with the learner's forward pass compiled (its compilation is in the
    warm-up, not in the figures)."""
    from ps_ray.rllib.algo import algo_config
    from ps_ray.rllib.ray_start import init_ray

    torch.set_num_threads(1)
    init_ray(num_cpus=1)
    algos = {"rllib": algo_config(spec).build_algo()}
    if compile:
        algos["rllib compiled"] = algo_config(spec, compile=True).build_algo()
    bare = BareTrainer(spec)
    for algo in algos.values():
        while algo.counters["updates"] < 100:
            algo.train()
    while bare.updates < 100:
        bare.step()
    rates = {side: [] for side in (*algos, "bare")}
    for _ in range(rounds):
        for side, algo in algos.items():
            counters = lambda a=algo: (a.counters["env_steps"], a.counters["updates"])  # noqa: E731
            rates[side].append(_measure(algo.train, counters, seconds))
        rates["bare"].append(_measure(bare.step, lambda: (bare.env_steps, bare.updates), seconds))
    for algo in algos.values():
        algo.stop()
    out = {}
    for side, values in rates.items():
        out[f"{side}_env_steps_per_s"] = float(np.mean([v[0] for v in values]))
        out[f"{side}_updates_per_s"] = float(np.mean([v[1] for v in values]))
    out["ratio"] = out["rllib_env_steps_per_s"] / out["bare_env_steps_per_s"]
    if compile:
        out["compiled_ratio"] = out["rllib compiled_updates_per_s"] / out["rllib_updates_per_s"]
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def main(argv: list[str] | None = None) -> None:
    parser = Parser(
        prog="ps-ray bench train", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", default="push")
    parser.add_argument("--method", default="ablation")
    parser.add_argument("--seconds", type=float, default=60.0, help="per measurement round")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--updates-per-step", type=float, default=0.4)
    parser.add_argument("--hidden", type=int, default=256)
    parser.add_argument("--compile", action="store_true", help="also RLlib with the learner compiled")
    args = parser.parse_args(argv)
    spec = TrainSpec(
        task=args.task,
        method=args.method,
        updates_per_step=args.updates_per_step,
        hidden=args.hidden,
        eval_every=10**9,
        learning_starts=500,
        random_episodes=2,
    )
    figures = run(spec, args.seconds, args.rounds, args.compile)
    print(
        f"task {args.task}, method {args.method}, hidden {spec.hidden}, batch {spec.batch_size}, "
        f"{spec.updates_per_step} updates per env step, {spec.num_envs} envs, 1 torch thread"
    )
    print(f"{'':<16}{'env steps/s':>13}{'updates/s':>11}{'ms/update':>11}")
    for side in ("rllib", *(["rllib compiled"] if args.compile else []), "bare"):
        steps, updates = figures[f"{side}_env_steps_per_s"], figures[f"{side}_updates_per_s"]
        print(f"{side:<16}{steps:>13.1f}{updates:>11.1f}{1e3 / updates:>11.1f}")
    print(f"peak RSS {figures['peak_rss_mb']:.0f} MB (all trainers in one process)")
    print(f"ratio {figures['ratio']:.2f}")
    if args.compile:  # ms/update includes the env steps between updates
        print(f"compiled / eager updates per second: {figures['compiled_ratio']:.2f}")


if __name__ == "__main__":
    main()
