"""The orchestration: every module here runs or records the sweep's stages with Ray Tune and
MLflow. ``run`` (``ps-ray run``: the stages in order), ``sweep`` (the train stage: plain sources,
anchors, the grid), ``zero_shot``, ``few_shot``, ``trials`` (the one Tune runner), ``progress``
(the live view), ``layout`` (every path of a sweep folder), ``tracking`` (MLflow, no Ray),
``tune_tracking`` (the Tune callback that feeds it) and ``cost`` (a sweep's projected cost).

Importing this package loads no Ray: the report reads stored results through ``layout`` and
``tracking`` alone. Everything the stages build on (envs, nets, policy files, stitching,
evaluation) lives outside it and never imports Ray or MLflow."""
