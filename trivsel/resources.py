"""Memory checks before large allocations: a request that cannot fit is refused at once with
the estimate, instead of failing later with a MemoryError (or swapping the machine to a halt)."""

from __future__ import annotations

import os

from .exceptions import InputError

__all__ = ["available_bytes", "check_memory", "GRID_BYTES_PER_POINT", "MESH_BYTES_PER_POINT"]

#: Bytes per point of grid data (float coordinates, integer coordinates, values) and the
#: temporaries that build it.
GRID_BYTES_PER_POINT = 112
#: A lower bound on the bytes per original point of a reduction's mesh state (tetrahedra,
#: links, point buckets, residuals, the swap memory), of which the kernel touches at least
#: this much on grids; the refusal uses the bound, so it never refuses a run that fits.
MESH_BYTES_PER_POINT = 500


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
    """One-line InputError when ``nbytes`` exceeds the memory available now."""
    avail = available_bytes()
    if avail is not None and nbytes > avail:
        raise InputError(f"{what} needs about {nbytes / 2**30:.3g} GiB, more than the {avail / 2**30:.3g} GiB "
                         "of memory available")
