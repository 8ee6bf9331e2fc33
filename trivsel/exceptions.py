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
