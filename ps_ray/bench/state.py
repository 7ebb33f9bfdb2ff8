"""What crash safety costs: the atomic write, the folder lock, and sealing / verifying a training
checkpoint, each next to its unsafe counterpart; with ``--replay``, what a trial writes to shared
storage per checkpoint and per hour, the whole buffer each time against its segments
(:mod:`ps_ray.store.replay`), at the paper's buffer size (figures, never assertions)."""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

from ps_ray.cli.args import Parser, positive_int
from ps_ray.store import checkpoint
from ps_ray.store.atomic import write_text
from ps_ray.store.lock import folder_lock


def _per_call(fn, n: int) -> float:
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - start) / n


def main(argv: list[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench state", description=__doc__)
    parser.add_argument("--checkpoint", default=None, help="a training checkpoint folder to seal and verify")
    parser.add_argument("--repeats", type=positive_int, default=200)
    parser.add_argument(
        "--replay",
        type=positive_int,
        default=None,
        metavar="EPISODES",
        help="also time replay checkpoints of a buffer holding this many push episodes (paper: 20000)",
    )
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats must be positive, got {args.repeats}")
    text = '{"env_steps": 12000, "eval_success": 0.95}' * 20  # about 1 KB
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        plain = _per_call(lambda: (root / "plain.json").write_text(text), args.repeats)
        atomic = _per_call(lambda: write_text(root / "atomic.json", text), args.repeats)

        def lock_once():
            with folder_lock(root / "locked", "run"):
                pass

        lock = _per_call(lock_once, args.repeats)
        print(f"1 KB file: plain write {plain * 1e3:.3f} ms, atomic (fsync + rename) {atomic * 1e3:.3f} ms")
        print(f"folder lock: acquire + release {lock * 1e3:.3f} ms (once per command, not per result)")
        if args.checkpoint:
            source = Path(args.checkpoint)
            folder = root / "checkpoint"
            shutil.copytree(source, folder)
            (folder / checkpoint.MANIFEST).unlink(missing_ok=True)
            size = sum(p.stat().st_size for p in folder.iterdir()) / 1e6
            seal = _per_call(lambda: checkpoint.seal(folder), 5)
            verify = _per_call(lambda: checkpoint.verify(folder), 5)
            copy = _per_call(lambda: shutil.copytree(folder, root / f"copy{time.perf_counter_ns()}"), 5)
            print(
                f"checkpoint of {size:.1f} MB: seal {seal * 1e3:.1f} ms, verify {verify * 1e3:.1f} ms, "
                f"against {copy * 1e3:.1f} ms to copy it (what Tune does with every checkpoint)"
            )
        if args.replay:
            replay_checkpoints(args.replay, root)


def replay_checkpoints(held: int, root: Path, checkpoints: int = 5) -> None:
    """A full buffer of ``held`` push episodes, checkpointed ``checkpoints`` times, each after one
    checkpoint interval of new episodes (TrainSpec defaults): the whole buffer as one .npz (before)
    against its segments (after). Per hour from this machine's rates (ps_ray.analysis.cost)."""
    import numpy as np

    from ps_ray.analysis.cost import load_rates
    from ps_ray.bench.her import PUSH_SPEC, A, T
    from ps_ray.data.her import HindsightReplay
    from ps_ray.envs.goals import goal_reward
    from ps_ray.specs.train import TrainSpec
    from ps_ray.store import replay

    spec = TrainSpec(robot="panda", task="push", hidden=256)
    interval = spec.checkpoint_every * spec.episodes_per_step  # episodes between checkpoints
    rates = load_rates()
    step_s = rates.env_step_s + spec.updates_per_step * rates.update_s(spec)
    per_hour = 3600 / (interval * T * step_s)
    rng = np.random.default_rng(0)
    chunk = {k: rng.standard_normal((interval, T + 1, *s)).astype(dt) for k, (s, dt) in PUSH_SPEC.items()}
    actions = rng.uniform(-1, 1, (interval, T, A)).astype(np.float32)
    buffer = HindsightReplay(PUSH_SPEC, A, T, held, goal_reward, seed=0)
    while buffer.episodes_added < held:
        buffer.add_episodes(chunk, actions)
    store, manifest = root / "segments", replay.write(buffer, root / "segments")  # the trial so far
    whole_bytes, whole_s, part_bytes, part_s = [], [], [], []
    for _ in range(checkpoints):
        buffer.add_episodes(chunk, actions)
        start = time.perf_counter()
        buffer.save(root / "replay.npz")
        whole_s.append(time.perf_counter() - start)
        whole_bytes.append((root / "replay.npz").stat().st_size)
        before = {p.name for p in store.iterdir()}
        start = time.perf_counter()
        new = replay.write(buffer, store, manifest)
        replay.prune(store, manifest, new)
        part_s.append(time.perf_counter() - start)
        part_bytes.append(sum(e["bytes"] for e in new["segments"] if e["file"] not in before))
        manifest = new
    mb = lambda b: np.mean(b) / 1e6  # noqa: E731
    print(
        f"replay checkpoints, buffer of {held:,} push episodes, a checkpoint every {interval} "
        f"episodes ({per_hour:.0f} per trial-hour at hidden 256 with {rates.source.split(' (')[0]}):"
    )
    for name, sizes, seconds in (("whole buffer", whole_bytes, whole_s), ("segments", part_bytes, part_s)):
        print(
            f"  {name:13} {mb(sizes):8.1f} MB and {np.mean(seconds) * 1e3:7.0f} ms per checkpoint, "
            f"{mb(sizes) * per_hour / 1e3:6.2f} GB per trial-hour"
        )
    print(f"  written per checkpoint, segments / whole: {np.mean(part_bytes) / np.mean(whole_bytes):.3f}")


if __name__ == "__main__":
    main()
