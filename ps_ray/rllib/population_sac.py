"""PopulationSAC: several sources trained in one learner (:class:`ps_ray.specs.population.PopulationSpec`).

A population is a co-trained grid whose cells share nothing: member i is cell (i, i) of a grid
with one task module and one robot module per member (:mod:`ps_ray.rllib.grid_module`), so its
loss, gradients, temperature and Adam slots are its own, and one update of the population is one
update of each member (on a GPU, as one batched pass: :mod:`ps_ray.rllib.population_module`).
What makes each member its source rather than a grid's cell: it resets from its own source's
reset-seed block (:class:`ps_ray.envs.grid.GridEnv` ``seed_offsets``) and
its replay is seeded with its own seed; the population's own seed (its first member's) draws the
initial weights, the exploration noise and the warm-up actions. Stopping is per member
(:mod:`ps_ray.rllib.population_train`).
"""

from __future__ import annotations

from ray.rllib.core.rl_module.rl_module import RLModuleSpec

from ps_ray.rllib.grid_sac import GridSAC, GridSACConfig
from ps_ray.rllib.population_module import PopulationSACLearner, PopulationSACModule


class PopulationSACConfig(GridSACConfig):
    def __init__(self, algo_class=None):
        super().__init__(algo_class=algo_class or PopulationSAC)

    def get_default_learner_class(self):
        return PopulationSACLearner

    def get_default_rl_module_spec(self):
        return RLModuleSpec(module_class=PopulationSACModule)


class PopulationSAC(GridSAC):
    @classmethod
    def get_default_config(cls) -> PopulationSACConfig:
        return PopulationSACConfig()

    @property
    def run_seed(self) -> int:
        """0: each member's env adds its own block's start (``seed_offsets``), so a member draws
        the reset seeds its source would draw alone (the warm-up actions, drawn for all members
        at once, come from the population's own seed, the first member's)."""
        return 0

    def replay_seeds(self) -> list[int]:
        """Each member's replay seed is its own seed, as its source's alone."""
        return list(self.config.model_config["member_seeds"])
