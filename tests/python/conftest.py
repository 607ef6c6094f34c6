"""pytest configuration shared by all Python tests: the learning package imports from the source tree."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src" / "quad_il" / "src"))
