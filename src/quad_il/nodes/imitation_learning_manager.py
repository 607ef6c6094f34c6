#!/usr/bin/env python3
"""imitation_learning_manager.py CONFIG.yaml: the interactive imitation-learning pipeline from one YAML file.

Thin entry point; the logic is quad_il.manager (docs/imitation_learning.md). Runs from the source tree
(`python src/quad_il/nodes/imitation_learning_manager.py config/il_manager.yaml`) or via rosrun after a build.
"""

import sys
from pathlib import Path

try:
    from quad_il.manager.cli import main
except ImportError:  # not built/sourced: use the package from the source tree next to this script
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from quad_il.manager.cli import main

if __name__ == "__main__":
    sys.exit(main())
