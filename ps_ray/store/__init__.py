"""The on-disk store, read and written without Ray or torch: a sweep folder's layout
(:mod:`~ps_ray.store.layout`), its stage markers (:mod:`~ps_ray.store.stages`), the readers of
Tune's attempt folders (:mod:`~ps_ray.store.attempts`), a run folder's file names
(:mod:`~ps_ray.store.run_layout`) and its checkpoint swap (:mod:`~ps_ray.store.run_folder`), the
sealed checkpoint (:mod:`~ps_ray.store.checkpoint`) and its replay segments
(:mod:`~ps_ray.store.replay`), the atomic write, the folder lock and the pickle-free npz reader.
docs/state.md describes the formats. Analysis reads a sweep only through this package; the Tune
stages (:mod:`ps_ray.pipeline`) write through it."""
