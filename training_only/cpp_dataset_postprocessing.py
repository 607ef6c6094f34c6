#!/usr/bin/env python3
"""Convert cpp_data_collector shards to an .npz of fixed-size arrays (the training contract).

    training_only/cpp_dataset_postprocessing.py IN_DIR [IN_DIR ...] OUT.npz
        [--num-ctrl-pts 10] [--horizon-s 2.0] [--on-corrupt raise|skip] [--compress]

Thin entry point: the work is quad_il.data.postprocess (format and resampling: docs/data_format.md).
"""

import sys
from pathlib import Path

# Runnable from a plain checkout too: the ROS-free package lives in src/quad_il/src.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src" / "quad_il" / "src"))

from quad_il.data.postprocess import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
