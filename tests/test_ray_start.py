"""Starting Ray again when a busy machine made its node miss Ray's start-up deadline
(ps_ray.rllib.ray_start): Ray's own failure is injected, since a loaded machine cannot be ordered."""

import pytest
import ray

from ps_ray.rllib.ray_start import RAY_START_TRIES, init_ray

TIMED_OUT = "The current node timed out during startup. This could happen because some of the raylet failed"


@pytest.fixture
def no_ray_here(monkeypatch):
    """This process as if no Ray ran in it (another test of the worker may have started one, which
    must survive): ``ray.shutdown`` calls are counted, not made."""
    shutdowns = []
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "shutdown", lambda: shutdowns.append(True))
    return shutdowns


def test_a_start_up_timeout_is_tried_again_and_other_errors_are_not(monkeypatch, capsys, no_ray_here):
    calls = []

    def init(**kwargs):
        calls.append(kwargs)
        raise RuntimeError(TIMED_OUT if len(calls) == 1 else "bad address")

    monkeypatch.setattr(ray, "init", init)
    with pytest.raises(RuntimeError, match="bad address"):
        init_ray(address="local")
    assert len(calls) == 2 and calls[0] == calls[1]  # the same request again, then the other error
    assert calls[0]["address"] == "local" and calls[0]["include_dashboard"] is False
    assert len(no_ray_here) == 1  # the timed-out start was cleaned up before the second
    assert "timed out during startup (attempt 1); starting it again" in capsys.readouterr().out


def test_a_node_that_keeps_timing_out_fails_after_the_last_try(monkeypatch, no_ray_here):
    calls = []

    def init(**kwargs):
        calls.append(kwargs)
        raise RuntimeError(TIMED_OUT)

    monkeypatch.setattr(ray, "init", init)
    with pytest.raises(RuntimeError, match="timed out during startup"):
        init_ray(address="local")
    assert len(calls) == RAY_START_TRIES
