"""benchmarks/point_work.py adds its counters to a copy of the package by exact text
replacement: the texts it looks for must still be in the kernel's sources, once each."""

from pathlib import Path

import pytest
from conftest import load_benchmark_script

ROOT = Path(__file__).resolve().parents[1]


def _script():
    return load_benchmark_script("point_work")


def test_the_counters_go_into_a_copy_and_leave_the_package_alone(tmp_path):
    pw = _script()
    before = {rel: (ROOT / rel).read_text() for rel, _, _ in pw.PATCHES}
    pw.patched_copy(tmp_path)
    state = (tmp_path / "trivsel/mesh/state.py").read_text()
    n = int(before["trivsel/mesh/state.py"].split("N_COUNTERS = ", 1)[1].split()[0])
    assert f"N_COUNTERS = {n} + 12" in state
    for rel in ("trivsel/mesh/storage.py", "trivsel/mesh/criteria.py"):
        text = (tmp_path / rel).read_text()
        assert text.count(f"ctr[{n} + ") == 2  # the points and the calls of each size class
    assert {rel: (ROOT / rel).read_text() for rel in before} == before


def test_a_kernel_text_that_moved_is_reported(tmp_path, monkeypatch):
    pw = _script()
    monkeypatch.setattr(pw, "PATCHES", pw.PATCHES + [("trivsel/mesh/storage.py", "no such text", "x")])
    with pytest.raises(SystemExit, match="storage.py"):
        pw.patched_copy(tmp_path)
