"""`python -m ps_ray.cli ...`, as the `ps-ray` script."""

import sys

from ps_ray.cli.commands import main

sys.exit(main())
