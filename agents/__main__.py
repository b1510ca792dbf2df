"""`python -m agents ...` runs the `smpl-envs` command line."""
import sys

from .cli import main

sys.exit(main())
