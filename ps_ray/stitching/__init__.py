"""Stitching: the modules of trained policies (:mod:`~ps_ray.stitching.zoo`), the pairing rule
(:mod:`~ps_ray.stitching.rule`), stitched policies and their translations
(:mod:`~ps_ray.stitching.stitch`), a sweep's combinations and their controls
(:mod:`~ps_ray.stitching.matrix`), a stitched pair as one record (:mod:`~ps_ray.stitching.pairs`),
its evaluation and chance (:mod:`~ps_ray.stitching.evaluate`, :mod:`~ps_ray.stitching.chance`), the
policies named on the command line (:mod:`~ps_ray.stitching.sources`) and the paper's
combinations (:mod:`~ps_ray.stitching.paper`). Which pairs a stage stitches is its plan's
(:mod:`ps_ray.plan.zero_shot`)."""
