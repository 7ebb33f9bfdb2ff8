"""Each stage's trials as a pure function of the sweep spec and a catalogue of trained modules
(a :class:`ps_ray.stitching.zoo.ModuleZoo`): ``plan(spec, ...) -> list[record]``, every record
typed (:class:`ps_ray.specs.trial.TrainTrial`, :class:`ps_ray.specs.trial.GridTrial`,
:class:`ps_ray.stitching.pairs.StitchedPair`). No Ray, no torch, nothing read but the catalogue,
nothing written. A stage runs its plan on the catalogue of what was trained
(:func:`ps_ray.plan.catalogue.trained`); the cost model and ``ps-ray sweep --check`` run the same
plan on the catalogue the spec implies (:func:`ps_ray.plan.catalogue.planned`), so what is priced
is what runs. Each stage's plan in one shape, ``plan(spec, catalogue)``: ``stages.PLANS``.
Adding a stage: its record, its settings, its plan here (and its ``PLANS`` row), its runner in
``ps_ray.pipeline``."""
