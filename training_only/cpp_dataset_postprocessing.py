#!/usr/bin/env python3
"""Convert cpp_data_collector shards to an .npz of fixed-size arrays (the training contract).

    training_only/cpp_dataset_postprocessing.py IN_DIR [IN_DIR ...] OUT.npz
        [--num-ctrl-pts 10] [--horizon-s 2.0] [--on-corrupt raise|skip] [--compress]

Thin entry point: the work is quad_il.data.postprocess (format and resampling: docs/data_format.md).
"""

import sys

from quad_il.data.postprocess import main  # quad_il is installed in the venv (scripts/setup.sh)

if __name__ == "__main__":
    sys.exit(main())
