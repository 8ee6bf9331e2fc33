"""The one exception type for bad input: a one-line message naming the problem and the value."""


class InputError(ValueError):
    """Bad user input (NaN, duplicates, too few or coplanar points, bad fraction, ...).

    The CLI prints ``trivsel: error: <message>`` on one line and exits with status 2,
    writing no output files.
    """
