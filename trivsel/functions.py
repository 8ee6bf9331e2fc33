"""The five trivariate test functions of Table 1 (Hamann & Chen 1994, section 5).

Each is addressable by number (1-5) or by a short name (``quadratic``, ``saddle``,
``cubic``, ``exponential``, ``trigonometric``); :func:`trivsel.sample_grid` samples
one on the grid of eq. (18).
"""

from __future__ import annotations

import numpy as np

from .exceptions import InputError, shown

__all__ = ["FUNCTIONS", "resolve_function"]


def _f1(x, y, z):
    return 0.4 * (x**2 + y**2 + z**2)


def _f2(x, y, z):
    return 0.4 * (x**2 - y**2 - z**2)


def _f3(x, y, z):
    return 0.15 * (x**3 + 2 * x**2 * y - x * z**2 + 2 * y**2)


def _f4(x, y, z):
    return np.exp(-0.5 * (x**2 + y**2 + z**2))


def _f5(x, y, z):
    return 0.1 * (np.cos(np.pi * x) + np.cos(np.pi * y) + np.cos(np.pi * z))


#: number -> (short name, expression as printed in Table 1, callable)
FUNCTIONS = {
    1: ("quadratic", "0.4(x^2 + y^2 + z^2)", _f1),
    2: ("saddle", "0.4(x^2 - y^2 - z^2)", _f2),
    3: ("cubic", "0.15(x^3 + 2x^2y - xz^2 + 2y^2)", _f3),
    4: ("exponential", "exp(-0.5(x^2 + y^2 + z^2))", _f4),
    5: ("trigonometric", "0.1(cos(pi x) + cos(pi y) + cos(pi z))", _f5),
}
_BY_NAME = {name: num for num, (name, _, _) in FUNCTIONS.items()}


def resolve_function(function) -> int:
    """Return the Table-1 number (1-5) of ``function`` given as number or short name.

    Raises
    ------
    InputError
        For an unknown function, naming the bad value and the valid choices.
    """
    key = function
    if isinstance(key, str):
        s = key.strip().lower()
        if s in _BY_NAME:
            return _BY_NAME[s]
        if s.lstrip("f").isdigit():
            key = int(s.lstrip("f"))
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool) and int(key) in FUNCTIONS:
        return int(key)
    choices = ", ".join(f"{k} ({v[0]})" for k, v in FUNCTIONS.items())
    raise InputError(f"unknown function {shown(function)}: choose one of {choices}")
