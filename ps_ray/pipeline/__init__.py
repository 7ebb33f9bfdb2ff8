"""The orchestration: every module here runs or records the sweep's stages with Ray Tune and
MLflow, each stage running its plan (:mod:`ps_ray.plan`). ``run`` (``ps-ray run``: the stages in
order), ``stage`` (what every stage shares), ``sweep`` (the train stage: plain sources, anchors,
sources), ``grid``, ``zero_shot``, ``few_shot``, ``trials`` (the one Tune runner), ``search`` (a
search's scheduler), ``progress`` (the live view), ``tune_tracking`` (the Tune callback that feeds
MLflow), ``heap`` and ``preemption``.

Importing this package loads no Ray. The folder layout and MLflow are the store's
(:mod:`ps_ray.store.layout`, :mod:`ps_ray.store.tracking`), the cost model analysis'
(:mod:`ps_ray.analysis.cost`); everything the stages build on (envs, nets, policy files,
stitching, evaluation) lives outside this package and never imports Ray."""
