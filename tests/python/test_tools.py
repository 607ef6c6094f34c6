"""The test-summary and BENCH-format tools that the Makefile targets rely on."""

import textwrap

import pytest

from quad_il.tools.bench_check import (
    BenchFormatError,
    format_bench_line,
    parse_bench_line,
)
from quad_il.tools.bench_check import (
    main as bench_main,
)
from quad_il.tools.test_summary import main as summary_main


def test_bench_line_round_trip():
    line = format_bench_line("sim_rtf_320x240", 5.25, "x")
    assert line == "BENCH sim_rtf_320x240 5.25 x"
    parsed = parse_bench_line(line)
    assert (parsed.name, parsed.value, parsed.unit) == ("sim_rtf_320x240", 5.25, "x")


def test_non_bench_lines_are_ignored():
    assert parse_bench_line("benchmarking 3 worlds...") is None


@pytest.mark.parametrize(
    "line, why",
    [
        ("BENCH sim_rtf 5.2", "malformed"),
        ("BENCH Sim-RTF 5.2 x", "malformed"),
        ("BENCH sim_rtf fast x", "not a number"),
        ("BENCH sim_rtf nan x", "not finite"),
        ("BENCHMARK done", "malformed"),
    ],
)
def test_malformed_bench_lines_are_rejected_with_reason(line, why):
    with pytest.raises(BenchFormatError, match=why):
        parse_bench_line(line)


def test_bench_check_reports_missing_expected_name(tmp_path, capsys):
    out = tmp_path / "out.txt"
    out.write_text("BENCH a 1 ms\n")
    assert bench_main([str(out), "--expect", "a"]) == 0
    assert bench_main([str(out), "--expect", "b"]) == 1
    assert "missing: b" in capsys.readouterr().err


def test_summary_counts_pass_fail_skip(tmp_path, capsys):
    (tmp_path / "suite").mkdir()
    (tmp_path / "suite" / "r.xml").write_text(
        textwrap.dedent(
            """\
            <testsuite>
              <testcase classname="A" name="ok"/>
              <testcase classname="A" name="bad"><failure message="boom"/></testcase>
              <testcase classname="A" name="skip"><skipped/></testcase>
            </testsuite>"""
        )
    )
    assert summary_main([str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert "1 passed, 1 failed, 1 skipped" in out
    assert "FAILED r.xml: A.bad: boom" in out


def test_summary_with_no_results_is_an_error(tmp_path):
    assert summary_main([str(tmp_path)]) == 2


def test_bench_entry_point_names_unknown_component():
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    res = subprocess.run(
        ["bash", str(root / "scripts" / "bench.sh"), "no_such_component"], capture_output=True, text=True
    )
    assert res.returncode == 2
    assert "no benchmark for component 'no_such_component'" in res.stderr
