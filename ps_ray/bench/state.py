"""What crash safety costs: the atomic write, the folder lock, and sealing / verifying a training
checkpoint, each next to its unsafe counterpart (figures, never assertions)."""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

from ps_ray import checkpoint
from ps_ray.atomic import write_text
from ps_ray.cli_parsers import Parser, positive_int
from ps_ray.lock import folder_lock


def _per_call(fn, n: int) -> float:
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - start) / n


def main(argv: list[str] | None = None) -> None:
    parser = Parser(prog="ps-ray bench state", description=__doc__)
    parser.add_argument("--checkpoint", default=None, help="a training checkpoint folder to seal and verify")
    parser.add_argument("--repeats", type=positive_int, default=200)
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


if __name__ == "__main__":
    main()
