"""Stitching: the modules of trained policies (:mod:`~ps_ray.stitching.zoo`), stitched policies and
their checks and controls (:mod:`~ps_ray.stitching.stitch`), a sweep's matrix of pairs
(:mod:`~ps_ray.stitching.pairs`), the policies named on the command line
(:mod:`~ps_ray.stitching.sources`) and the paper's few-shot combinations
(:mod:`~ps_ray.stitching.paper`)."""
