"""Resources of a run: memory checks before large allocations (a request that cannot fit is
refused at once with the estimate, instead of failing later with a MemoryError or swapping the
machine to a halt), and long calls that Ctrl-C can still interrupt (:func:`interruptible`)."""

from __future__ import annotations

import os

from .exceptions import MemoryShortage

__all__ = ["available_bytes", "check_memory", "interruptible", "GRID_BYTES_PER_POINT", "MESH_BYTES_PER_POINT",
           "DELAUNAY_BYTES_PER_POINT"]

#: Bytes per point of grid data (float coordinates, integer coordinates, values) and the
#: temporaries that build it.
GRID_BYTES_PER_POINT = 112
#: A lower bound on the bytes per original point of a reduction's mesh state (tetrahedra,
#: links, point buckets, residuals, the swap memory), of which the kernel touches at least
#: this much on grids; the refusal uses the bound, so it never refuses a run that fits.
MESH_BYTES_PER_POINT = 500
#: Peak bytes per point of the whole reduction of scattered points by a method that
#: fits curvature: Qhull's Delaunay tetrahedralization of every point dominates (about
#: 6.5 tetrahedra per point).  Measured: 6.0 GB peak for 2e6 uniform points.
DELAUNAY_BYTES_PER_POINT = 3000


def available_bytes() -> int | None:
    """Memory available to new allocations (Linux's MemAvailable), or None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(nbytes: float, what: str) -> None:
    """One-line :class:`~trivsel.exceptions.MemoryShortage` (an InputError) when ``nbytes``
    exceeds the memory available now."""
    avail = available_bytes()
    if avail is not None and nbytes > avail:
        raise MemoryShortage(f"{what} needs about {nbytes / 2**30:.3g} GiB, more than the {avail / 2**30:.3g} GiB "
                             "of memory available", needed=nbytes, available=avail)


def interruptible(fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, run so that Ctrl-C interrupts it within a fraction of a second.

    Long calls into C that release the GIL (Qhull's hull and Delaunay triangulation
    of millions of points take minutes) would otherwise delay Python's signal handling
    until they return.  The call runs in a daemon thread while the calling thread waits
    in short steps, so KeyboardInterrupt is raised there at once; the abandoned call
    finishes in the background (or ends with the process).
    """
    import threading

    if threading.current_thread() is not threading.main_thread():
        return fn(*args, **kwargs)  # signals only reach the main thread anyway
    box = {}

    def run():
        try:
            box["value"] = fn(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread
            box["error"] = exc

    worker = threading.Thread(target=run, name=f"trivsel-{getattr(fn, '__name__', 'call')}", daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(0.05)
    if "error" in box:
        raise box["error"]
    return box["value"]
