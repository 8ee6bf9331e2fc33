"""Shared test settings.

* hypothesis profiles: CI runs the larger one (``CI=true``);
* tests marked ``slow`` run only with ``CI=true`` (as in CI) or ``--run-slow``, so that a
  plain ``python -m pytest`` is quick enough to run often.
"""

import os
import subprocess

import pytest
from hypothesis import HealthCheck, settings

IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")

# derandomized: the same cases every run, so a result never depends on the draw
settings.register_profile("dev", max_examples=150, deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("ci", max_examples=1000, deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if IN_CI else "dev")


def examples(scale):
    """A number of hypothesis examples that follows the profile: ``scale`` times its
    ``max_examples`` (for tests whose cases cost more or less than the usual), at least 1."""
    return max(1, round(scale * settings.default.max_examples))


def pytest_addoption(parser):
    parser.addoption("--run-slow", action="store_true", help="also run the tests marked slow (CI=true does)")


def pytest_collection_modifyitems(config, items):
    if IN_CI or config.getoption("--run-slow"):
        return
    skip = pytest.mark.skip(reason="slow: run with --run-slow or CI=true")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


def slurm_answers():
    """True when a SLURM answers sinfo (e.g. the local one of scripts/slurm-local.sh)."""
    try:
        r = subprocess.run(["sinfo", "-h", "-o", "%P %T"], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return r.returncode == 0 and bool(r.stdout.strip())


@pytest.fixture
def slurm():
    """Skip unless a SLURM answers; in CI (TRIVSEL_SLURM_REQUIRED, after scripts/slurm-local.sh
    start) fail instead, so a SLURM that did not start cannot pass as a skip."""
    if not slurm_answers():
        if os.environ.get("TRIVSEL_SLURM_REQUIRED"):
            pytest.fail("TRIVSEL_SLURM_REQUIRED is set but no SLURM answers `sinfo`")
        pytest.skip("no SLURM answers `sinfo` (start the local one: scripts/slurm-local.sh start)")


# The Snakemake options of the SLURM tests' status checks.  After a check that finds a job ended
# (the next jobs are submitted then), the executor plugin checks again after this many seconds,
# then 10 s later each time than the time before while none ends (its own rule; no option sets
# the step).  The tests' runs are chains of jobs of 5-6 s, up to 13 s when a job waits for a free
# CPU or the machine is busy: with 3, the checks come 3, 16 and 39 s after a submission, so the
# second one sees such a job end (with 5 it came after 20 s; with 1, after 12 s, and a job that
# took longer was seen only after 33 s).
SLURM_STATUS_CHECKS = ["--slurm-init-seconds-before-status-checks", "3"]


def sacct_rows(ids, fields, tries=60):
    """sacct's rows for SLURM job ``ids`` (``{id: {field: value}}``), once all are COMPLETED
    or after ``tries`` seconds (sacct lags the end of a job by about a second)."""
    import time

    cmd = ["sacct", "-X", "-n", "-P", "-j", ",".join(ids), "-o", ",".join(fields)]
    rows = {}
    for _ in range(tries):
        rows = {line.split("|")[0]: dict(zip(fields, line.split("|")))
                for line in subprocess.run(cmd, capture_output=True, text=True, timeout=60).stdout.splitlines()}
        if set(rows) == set(ids) and all(row["State"] == "COMPLETED" for row in rows.values()):
            break
        time.sleep(1)
    return rows


def made_once(tmp_path_factory, name, make):
    """The folder ``name`` that ``make(folder)`` fills, made once for the whole test run and
    shared by the tests that only read it (or copy it).  Under pytest-xdist the workers' base
    folders sit side by side in the run's own: the first worker to ask makes the folder there
    while holding a lock, and the others wait for it and then read the same folder.  A
    ``make`` that fails leaves no mark, so the next test to ask tries again (and fails the
    same way)."""
    import shutil

    try:
        import fcntl
    except ImportError:  # no flock(2): each worker makes its own
        fcntl = None
    root = tmp_path_factory.getbasetemp()
    if fcntl is not None and os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    folder, done = root / name, root / f"{name}.done"
    with open(root / f"{name}.lock", "w") as lock:
        if fcntl is not None:
            fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            if folder.exists():
                shutil.rmtree(folder)
            folder.mkdir()
            make(folder)
            done.write_text("")
    return folder


def load_benchmark_script(name):
    """A script of benchmarks/ as a module (they are not a package)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
