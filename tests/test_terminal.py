"""What reaches the terminal (ps_ray.store.terminal): Ray's and MLflow's notices go to a log file."""

from __future__ import annotations

import io
import logging

from ps_ray.pipeline.progress import eta_s
from ps_ray.store.terminal import VERBOSE_ENV, others_to


def test_notices_go_to_the_log_and_every_handler_gets_its_stream_back(tmp_path, monkeypatch):
    monkeypatch.delenv(VERBOSE_ENV, raising=False)
    shared = logging.StreamHandler(io.StringIO())  # one handler on two loggers
    before = shared.stream
    for name in ("ray", "mlflow"):
        logging.getLogger(name).addHandler(shared)
    try:
        with others_to(tmp_path / "logs" / "driver.log") as terminal:
            logging.getLogger("ray").warning("a ray notice")
            print("printed inside")
            terminal.write("")  # the real stdout stays reachable for ps_ray's own lines
        assert shared.stream is before and before.getvalue() == ""
        text = (tmp_path / "logs" / "driver.log").read_text()
        assert "a ray notice" in text and "printed inside" in text
    finally:
        for name in ("ray", "mlflow"):
            logging.getLogger(name).removeHandler(shared)


def test_verbose_leaves_everything_on_the_terminal(tmp_path, monkeypatch):
    monkeypatch.setenv(VERBOSE_ENV, "1")
    with others_to(tmp_path / "driver.log"):
        pass
    assert not (tmp_path / "driver.log").exists()


def test_the_eta_counts_work_not_trials():
    # two long trials half way after an hour, two waiting: three trials' work left, one per hour
    assert eta_s(3600, [(0.0, 0.5), (0.0, 0.5)], pending=2) == 3 * 3600
    # the steps a resumed trial brought from its checkpoint are not this run's pace
    assert eta_s(3600, [(0.5, 0.75)], pending=0) == 3600  # a quarter in an hour, a quarter left
    # trials without a budget count whole when they end; nothing ended: no estimate yet
    assert eta_s(60, [(1.0, 1.0), (0.0, 1.0), (0.0, 0.0)], pending=1) == 60 * 2
    assert eta_s(60, [(0.0, 0.0)], pending=3) is None
