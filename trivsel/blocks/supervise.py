"""Run Snakemake for ``trivsel blocks`` and stop it, with its jobs, when ``trivsel blocks`` dies.

``python supervise.py PARENT STOP_SECONDS COMMAND...`` (standard library only, so it starts fast):

* it runs in a session and process group of its own (``trivsel blocks`` starts it so), which
  ``COMMAND`` (Snakemake) and Snakemake's jobs share;
* it adopts the jobs Snakemake leaves behind (``PR_SET_CHILD_SUBREAPER``) and ends only once
  every process it started has ended, so the descriptor holding the run folder's lock,
  which it keeps open, is freed only when nothing runs in the folder any more;
* when ``trivsel blocks`` dies, however it dies (``PR_SET_PDEATHSIG``, Linux), it sends
  SIGTERM to the group, which the jobs answer by removing their temporary files, then
  SIGKILL after ``STOP_SECONDS``.  Snakemake alone would only stop starting jobs and wait
  for the running ones to finish.

Its exit status is Snakemake's (``128 + N`` if a signal ``N`` ended Snakemake).
"""

import ctypes
import os
import signal
import subprocess
import sys
import time

PR_SET_PDEATHSIG = 1
PR_SET_CHILD_SUBREAPER = 36
#: Sent to this process when ``trivsel blocks`` dies: a signal nothing else sends it.
PARENT_DIED = signal.SIGUSR1


def _prctl(option, value):
    try:
        ctypes.CDLL(None, use_errno=True).prctl(option, value)
    except (OSError, AttributeError):
        pass


def _reap(children):
    """Reap every ended child; record Snakemake's status.  False once no child is left."""
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return False
        if pid == 0:
            return True
        if pid == children["snakemake"]:
            children["status"] = status


def _default_signals():
    """In Snakemake's process, before it starts: SIGTERM and SIGINT as they were (an ignored
    signal stays ignored across ``exec``)."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def main(argv):
    parent, stop_seconds, command = int(argv[0]), float(argv[1]), argv[2:]
    died = []
    signal.signal(PARENT_DIED, lambda *_: died.append(True))
    _prctl(PR_SET_PDEATHSIG, int(PARENT_DIED))
    _prctl(PR_SET_CHILD_SUBREAPER, 1)
    # SIGTERM to the group (``trivsel blocks`` stopping the run) is for Snakemake and its
    # jobs; this process waits for them to end
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    children = {"snakemake": subprocess.Popen(command, preexec_fn=_default_signals).pid, "status": None}
    stop_at = None
    while _reap(children):
        if stop_at is None and (died or os.getppid() != parent):
            os.killpg(0, signal.SIGTERM)
            stop_at = time.monotonic() + stop_seconds
        elif stop_at is not None and time.monotonic() > stop_at:
            os.killpg(0, signal.SIGKILL)  # this process too: nothing is left holding the folder
        time.sleep(0.05)
    status = children["status"] or 0
    return os.WEXITSTATUS(status) if os.WIFEXITED(status) else 128 + os.WTERMSIG(status)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
