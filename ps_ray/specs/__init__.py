"""Typed specs, loaded strictly (no Ray, no torch): the training spec (:mod:`~ps_ray.specs.train`),
the sweep spec (:mod:`~ps_ray.specs.sweep`), methods (:mod:`~ps_ray.specs.methods`) and the
resources each stage's trials ask for (:mod:`~ps_ray.specs.resources`)."""
