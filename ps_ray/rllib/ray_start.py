"""Starting Ray in this process: ``ray.init``, started again when a busy machine made the local
node miss Ray's start-up deadline (Ray gives a new node's raylet a fixed 30 s to register with its
GCS; ``ray.init`` then fails with RAY_START_TIMEOUT in its message)."""

from __future__ import annotations

RAY_START_TIMEOUT = "timed out during startup"
RAY_START_TRIES = 3


def cluster_address() -> str | None:
    """The Ray cluster this process should join: ``RAY_ADDRESS`` (set by ``ray job submit`` and
    on a cluster's nodes), or None: start a local instance."""
    import os

    return os.environ.get("RAY_ADDRESS") or None


def init_ray(address: str = "local", **kwargs) -> None:
    """``ray.init(address, **kwargs)`` unless Ray runs in this process, quiet (no dashboard, no
    worker logs on the terminal, Ray's logging left alone), started again (up to RAY_START_TRIES
    times in all) when the local node timed out during its start-up."""
    import ray

    quiet = dict(include_dashboard=False, log_to_driver=False, configure_logging=False)
    for attempt in range(1, RAY_START_TRIES + 1):
        if ray.is_initialized():
            return
        try:
            ray.init(address=address, **{**quiet, **kwargs})
            return
        except Exception as e:
            if RAY_START_TIMEOUT not in str(e) or attempt == RAY_START_TRIES:
                raise
            print(f"Ray's node {RAY_START_TIMEOUT} (attempt {attempt}); starting it again", flush=True)
            ray.shutdown()
