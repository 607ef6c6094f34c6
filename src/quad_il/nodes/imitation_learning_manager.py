#!/usr/bin/env python3
"""imitation_learning_manager.py CONFIG.yaml: the interactive imitation-learning pipeline from one YAML file.

Thin entry point; the logic is quad_il.manager (docs/imitation_learning.md). Runs from the source tree
(`python src/quad_il/nodes/imitation_learning_manager.py config/il_manager.yaml`) or via rosrun after a build.
"""

import sys

from quad_il.manager.cli import main  # installed in the venv (scripts/setup.sh) and in the devel space

if __name__ == "__main__":
    sys.exit(main())
