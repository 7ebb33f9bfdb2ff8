"""Ray-free, torch-free data of training and stitching: the hindsight replay buffer
(:mod:`~ps_ray.data.her`), anchor selection by k-means (:mod:`~ps_ray.data.anchors`) and the
anchor and task-state files (:mod:`~ps_ray.data.anchor_file`)."""
