"""`ps-ray`: the commands (commands.py) and their arguments (parsers.py)."""

from ps_ray.cli.commands import main

__all__ = ["main"]
