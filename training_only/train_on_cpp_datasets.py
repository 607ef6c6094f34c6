#!/usr/bin/env python3
"""Train the policy on collected datasets (behaviour cloning, thesis section 3.9). Thin entry point.

The command line, its outputs and exit statuses are those of quad_il.learning.train (run `--help`); the same
command works under torchrun (docs/scaling.md). quad_il is installed in the venv (scripts/setup.sh).
"""

import sys

from quad_il.learning.train import main

if __name__ == "__main__":
    sys.exit(main())
