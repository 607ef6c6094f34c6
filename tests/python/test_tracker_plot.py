"""kr_tracker's step-response plot: the CSV written by tracker_eval is read back exactly, bad files are
rejected with the reason, and the PNG has the three panels' figure size."""

from __future__ import annotations

import importlib.util
import math
import struct
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "src" / "kr_tracker" / "scripts" / "plot_step_response.py"
HEADER = "t_s,x_m,y_m,z_m,x_ref_m,y_ref_m,z_ref_m,vx_mps,vy_mps,vz_mps,yaw_rad,yaw_ref_rad"


def _load_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("plot_step_response", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


plot = _load_module()


def _write_run(path: Path, rows: list[list[float]], header: str = HEADER) -> None:
    path.write_text(header + "\n" + "\n".join(",".join(repr(v) for v in r) for r in rows) + "\n")


def _step_rows(n: int = 200) -> list[list[float]]:
    rows = []
    for i in range(n):
        t = 0.005 * i
        ref = 0.0 if t < 0.2 else 3.0
        y = 0.0 if t < 0.2 else 3.0 * (1.0 - math.exp(-(t - 0.2) / 0.15))
        rows.append([t, y, y, 1.0 + y, ref, ref, 1.0 + ref, 0.0, 0.0, 0.0, 0.0, 0.0])
    return rows


def test_run_csv_round_trips_every_value(tmp_path: Path) -> None:
    rows = _step_rows()
    csv_path = tmp_path / "run.csv"
    _write_run(csv_path, rows)
    run = plot.load_run(csv_path)
    expected = np.array(rows)
    for j, name in enumerate(HEADER.split(",")):
        np.testing.assert_array_equal(run[name], expected[:, j])


def test_plot_writes_a_png_of_the_figure_size(tmp_path: Path) -> None:
    csv_path = tmp_path / "run.csv"
    _write_run(csv_path, _step_rows())
    png = tmp_path / "out" / "step.png"
    assert plot.main([str(csv_path), str(png), "--title", "step"]) == 0
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    assert (width, height) == (800, 750)


@pytest.mark.parametrize(
    ("header", "row", "message"),
    [
        ("t_s,x_m,y_m,z_m", [0.0, 1.0, 2.0, 3.0], "missing column(s) x_ref_m, y_ref_m, z_ref_m"),
        (HEADER, [0.0, float("nan"), 0, 0, 0, 0, 0, 0, 0, 0, 0, 0], "column x_m has non-finite values"),
    ],
)
def test_bad_files_are_rejected_with_the_reason(
    tmp_path: Path, header: str, row: list[float], message: str
) -> None:
    csv_path = tmp_path / "bad.csv"
    _write_run(csv_path, [row], header)
    with pytest.raises(plot.RunFormatError, match=message.replace("(", r"\(").replace(")", r"\)")):
        plot.load_run(csv_path)


def test_non_numeric_empty_and_unordered_files_are_rejected(tmp_path: Path) -> None:
    bad = tmp_path / "text.csv"
    bad.write_text(HEADER + "\n0,a,0,0,0,0,0,0,0,0,0,0\n")
    with pytest.raises(plot.RunFormatError, match="column x_m has a non-numeric value"):
        plot.load_run(bad)
    empty = tmp_path / "empty.csv"
    empty.write_text(HEADER + "\n")
    with pytest.raises(plot.RunFormatError, match="no samples"):
        plot.load_run(empty)
    unordered = tmp_path / "unordered.csv"
    _write_run(unordered, [_step_rows()[1], _step_rows()[0]])
    with pytest.raises(plot.RunFormatError, match="time is not strictly increasing"):
        plot.load_run(unordered)
