"""`ps-ray`: the commands (commands.py), their arguments (parsers.py) and the argument types
(args.py). The commands load on the first call, so ``ps_ray.cli.args`` imports nothing else."""


def main(argv: list[str] | None = None) -> int:
    from ps_ray.cli.commands import main as run

    return run(argv)


__all__ = ["main"]
