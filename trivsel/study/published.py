"""The published Table 1 of Hamann & Chen (1994) and the paper's labels of its functions.

``table1_published.csv`` beside this module holds Table 1 as printed (n = 16): E_RMS over all
grid points and over the interior points, for the five functions of section 5 at 50, 20 and
10 %.
"""

from __future__ import annotations

from importlib import resources

import pandas as pd

from ..functions import FUNCTIONS

__all__ = ["PUBLISHED_SOURCE", "function_label", "load_published"]

_KIND = {
    "quadratic": "Quadratic polynomial",
    "saddle": "Quadratic polynomial",
    "cubic": "Cubic polynomial",
    "exponential": "Exponential function",
    "trigonometric": "Trigonometric function",
}

PUBLISHED_SOURCE = ("Hamann, B. and Chen, J.-L. (1994), Data point selection for piecewise trilinear "
                    "approximation, Table 1 (n = 16)")


def function_label(num: int, with_number: bool = True) -> str:
    """'4. Exponential function: exp(-0.5(x^2 + y^2 + z^2))' as in Table 1."""
    short, expr, _ = FUNCTIONS[int(num)]
    label = f"{_KIND.get(short, short.capitalize())}: {expr}"
    return f"{int(num)}. {label}" if with_number else label


def load_published(path=None) -> pd.DataFrame:
    """Published Table 1: columns function, expression, fraction, E_rms, E_rms_interior."""
    if path is None:
        with resources.files("trivsel.study").joinpath("table1_published.csv").open("r") as fh:
            df = pd.read_csv(fh)
    else:
        df = pd.read_csv(path)
    df["function"] = df["function"].astype(int)
    df["fraction"] = df["fraction"].astype(float)
    return df
