"""The SLURM jobs of a ``trivsel blocks`` run: found by job name, cancelled, and read back.

Snakemake's SLURM executor names every job of a run after the run's UUID, with an optional
prefix (``--slurm-jobname-prefix``).  ``trivsel blocks`` gives each output folder its own
prefix (:func:`job_prefix`), so the jobs of any run in that folder, including one whose
driver was killed, can be found with ``squeue``/``sacct`` and cancelled with ``scancel``.
Every function here does nothing (and returns nothing) where SLURM's commands are missing.
"""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import time
from pathlib import Path

#: sacct/squeue states of a job that ended without success (sacct writes "CANCELLED by UID").
FAILED_STATES = ("BOOT_FAIL", "CANCELLED", "DEADLINE", "FAILED", "NODE_FAIL", "OUT_OF_MEMORY", "PREEMPTED",
                 "TIMEOUT")


def job_prefix(out):
    """The SLURM job-name prefix of the runs in folder ``out``: ``trivsel-`` and 12 hex digits
    of the folder's absolute path (the executor plugin allows letters, digits, ``_`` and ``-``)."""
    digest = hashlib.sha256(str(Path(out).resolve()).encode()).hexdigest()
    return f"trivsel-{digest[:12]}"


def available():
    """Whether SLURM's client commands are on PATH."""
    return all(shutil.which(c) for c in ("squeue", "scancel", "sacct"))


def _run(cmd, timeout=60):
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return ""
    return r.stdout if r.returncode == 0 else ""


def active_jobs(prefix):
    """``[(job id, state)]`` of the queued or running jobs whose name starts with ``prefix_``."""
    if not available():
        return []
    rows = (line.split("|") for line in _run(["squeue", "--me", "-h", "-o", "%i|%j|%T"]).splitlines())
    return [(r[0], r[2]) for r in rows if len(r) == 3 and r[1].startswith(prefix + "_")]


def cancel_jobs(prefix, *, wait=60.0):
    """Cancel every queued or running job named ``prefix_*`` and wait up to ``wait`` seconds
    until SLURM has ended them.  Returns the cancelled job ids."""
    ids = [i for i, _ in active_jobs(prefix)]
    if not ids:
        return []
    _run(["scancel", *ids])
    end = time.monotonic() + wait
    while time.monotonic() < end and any(i in ids for i, _ in active_jobs(prefix)):
        time.sleep(0.5)
    return ids


def end_with_parent():
    """In the Snakemake process that a SLURM job's batch script runs: be killed (SIGKILL) when the
    script's shell ends first (``PR_SET_PDEATHSIG``, Linux; elsewhere nothing).  A cancellation's
    SIGTERM kills the shell at once, while Snakemake waits for its running job; adopted by init, it
    is no longer below the job's ``slurmstepd``, where a SLURM that finds a job's processes by their
    parents (``proctrack/linuxproc``) looks for what to kill, so if it waits on (for a job it still
    counts as running), nothing ends it.  Otherwise the shell waits for it, so the signal comes only
    when the job is being ended."""
    import ctypes
    import os
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() == 1:  # the parent ended before the line above
        os.kill(os.getpid(), signal.SIGKILL)


def failed_jobs(prefix, since):
    """``[(job id, state, comment)]`` of the jobs named ``prefix_*`` submitted at or after
    ``since`` (seconds since the epoch) that ended without success, in submission order."""
    if not available():
        return []
    start = time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(since - 1))
    text = _run(["sacct", "-X", "-n", "-P", "-S", start, "-o", "JobIDRaw,JobName,Submit,State,Comment"])
    out = []
    for line in text.splitlines():
        r = line.split("|", 4)
        if (len(r) == 5 and r[1].startswith(prefix + "_") and r[2] >= start
                and r[3].split(" ")[0] in FAILED_STATES):
            out.append((r[0], r[3], r[4]))
    return sorted(out, key=lambda r: int(r[0]) if r[0].isdigit() else 0)
