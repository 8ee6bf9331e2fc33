"""The one exception type for bad input: a one-line message naming the problem and the value."""

import numbers


class InputError(ValueError):
    """Bad user input (NaN, duplicates, too few or coplanar points, bad fraction, ...).

    The CLI prints ``trivsel: error: <message>`` on one line and exits with status 2,
    writing no output files.
    """


class MemoryShortage(InputError):
    """A run that needs more memory than is available now (an :class:`InputError`).

    ``needed`` and ``available`` are in bytes; the CLI adds the ``trivsel blocks`` command
    line that does the job in bounded memory, where there is one.
    """

    def __init__(self, message, *, needed, available):
        super().__init__(message)
        self.needed, self.available = float(needed), float(available)


def check_threads(threads):
    """``threads`` as an int >= 1; one-line InputError otherwise."""
    if isinstance(threads, bool) or not isinstance(threads, numbers.Integral) or threads < 1:
        raise InputError(f"threads must be an integer >= 1, got {shown(threads)}")
    return int(threads)


def is_real(value) -> bool:
    """Whether ``value`` is one real number: an int, a float or a NumPy real scalar, not a bool,
    a string, a complex number, a sequence or an array."""
    import numpy as np

    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def check_tolerance(name, tol):
    """``tol`` as a float: None, or one finite real number >= 0; one-line InputError otherwise."""
    import math

    if tol is None:
        return None
    if not is_real(tol) or not math.isfinite(tol) or tol < 0:
        raise InputError(f"{name} must be a finite number >= 0, got {shown(tol)}")
    return float(tol)


def check_count(count, n_points):
    """``count`` as an int: None, or one whole number from 1 to ``n_points``; one-line
    InputError otherwise (a float that is whole, ``30.0``, is taken)."""
    import math

    if count is None:
        return None
    if not is_real(count) or not math.isfinite(count) or int(count) != count or not 1 <= count <= n_points:
        raise InputError(f"count must be an integer in [1, {n_points}], got {shown(count)}")
    return int(count)


def check_callable(name, fn):
    """``fn``: None or a callable; one-line InputError otherwise."""
    if fn is not None and not callable(fn):
        raise InputError(f"{name} must be a function (or None), got {shown(fn)}")
    return fn


def one_line(exc, *, first: bool = False) -> str:
    """An exception's message on one line, for an :class:`InputError` that quotes it.

    ``first``: only its first line (Qhull's and pandas' messages go on for a page);
    otherwise all of it, joined (some file readers break one sentence over lines).
    """
    text = str(exc).strip()
    if first:
        text = text.splitlines()[0] if text else ""
    return " ".join(text.split()) or type(exc).__name__


def shown(value) -> str:
    """``repr`` of a value for a message, with NumPy scalars and arrays as plain Python
    (``0.5``, not ``np.float64(0.5)``; ``[1, 2]``, not ``array([1, 2])``)."""
    tolist = getattr(value, "tolist", None)
    if tolist is not None and type(value).__module__ == "numpy":
        value = tolist()
    return repr(value)
