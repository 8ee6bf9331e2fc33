"""The options of a reduction, defined once.

:class:`Options` is a frozen dataclass with one field per choice of the method:
the choices the paper leaves open (sections 2-5) and the extensions beyond it.
Each field carries its choices, default, documentation, the paper's reference,
its command-line flag and its short tag as metadata, and everything else is
generated from it:

* the ``trivsel reduce`` flags (:func:`add_arguments`, :func:`from_namespace`);
* the keyword arguments and signature of :func:`trivsel.reduce`;
* the workflow's sweep axes, path tags and command lines (:func:`variant_tag`,
  :meth:`Options.cli_args`) and its config schema (:func:`config_schema`);
* the ablation's choices and the options table in ``docs/options.md``
  (:func:`options_markdown`).

A field whose default is ``None`` takes the default of the chosen method
(``DEFAULTS`` of the method's module in :mod:`trivsel.methods`); after
:meth:`Options.resolve` every field that applies to the method has a concrete
value.  Each field names the methods it applies to (``methods``; all when
absent): a value other than its default for another method is refused, and
``--help``, the docs and the workflow's schema group the options by it.

Regenerate the generated files with ``python -m trivsel.options``.
"""

from __future__ import annotations

import argparse
import math
import numbers
from dataclasses import asdict, dataclass, field, fields, replace

from .exceptions import InputError, shown
from .selection import TIE_ORDERS

__all__ = ["Options", "option_fields", "add_arguments", "from_namespace", "variant_tag", "config_schema",
           "options_markdown", "METHOD_DEFAULT", "applies", "check_applicable", "option_groups"]

#: How the docs and ``--help`` show a default that depends on the method.
METHOD_DEFAULT = "method's default"


#: The options of every method that inserts points and swaps after each insertion: the
#: methods whose module says ``INSERTS = True`` (:mod:`trivsel.methods`), so that a new
#: inserting method takes them without a change here.
INSERTING = "inserting"
#: The largest integer option: what an int64 holds
INT_MAX = 2**63 - 1


def _option(default, doc, *, kind, choices=None, paper=None, tag, flag=None, minimum=None, maximum=None,
            sequence=False, methods=None):
    """A dataclass field with the metadata of one option.

    ``kind`` is ``"choice"``, ``"bool"``, ``"int"`` or ``"float"``; ``sequence``
    means the value is a tuple of choices (``values``).  ``minimum`` and ``maximum`` bound
    numbers (inclusive); an integer is at most ``INT_MAX`` unless its ``maximum`` says less.  ``methods`` names the methods the option applies to
    (``None``: every method); setting it for another method is an error.
    """
    meta = dict(doc=doc, kind=kind, choices=None if choices is None else tuple(choices), paper=paper, tag=tag,
                flag=flag, minimum=minimum, maximum=INT_MAX if maximum is None and kind == "int" else maximum,
                sequence=sequence,
                methods=methods if methods in (None, INSERTING) else tuple(methods))
    return field(default=default, metadata=meta)


def _method_names():
    from .methods import METHODS

    return tuple(METHODS)


@dataclass(frozen=True)
class Options:
    """Every choice of a reduction (:func:`trivsel.reduce`); see ``docs/options.md``.

    Construct with keywords; every value is checked at once and a bad one raises
    :class:`~trivsel.exceptions.InputError` naming the option and the value.
    Fields defaulting to ``None`` take the method's default (:meth:`resolve`).
    """

    method: str = _option(
        "paper", "point selection: 'paper' ranks by absolute curvature (sections 2-4); 'greedy' inserts the "
        "worst-approximated point next (error-driven, Garland & Heckbert 1995 lifted to 3-D); 'decimate' "
        "removes points from the full mesh (a grid, the Delaunay tetrahedra of scattered points, or a mesh's "
        "own tetrahedra) by the half-edge collapse that raises the squared error least (aims at E_RMS); "
        "'auto' (the default for data: trivsel reduce INPUT, reduce(data)) is 'decimate' for data (or, "
        "given options of the inserting methods only, the first of those that takes them) and 'paper' for a "
        "Table-1 function",
        kind="choice", paper="sections 2-4", tag="method")
    criterion: str | None = _option(
        None, "swap criterion: sum of the tetrahedral RMS errors (eq. 14) 'rms', of the max errors (eq. 15) "
        "'max', or the squared residuals of the configuration's points, each once 'sse' (the exact change of "
        "the global L2 error); for 'decimate' the order of the collapses: 'sse' (the change of the squared "
        "error, aims at E_RMS) or 'max' (the largest residual left, aims at E_inf)",
        kind="choice", choices=("rms", "max", "sse"), paper="section 4, eqs. 14-15", tag="crit")
    candidates: str = _option(
        "all", "selectable points: 'all' non-fixed points (face and edge points included; Table 1 needs them) "
        "or 'interior' only",
        kind="choice", choices=("all", "interior"), paper="section 3", tag="cand")
    tie_order: str = _option(
        "index", "order among equal quantised curvatures: 'index' (C order over (i, j, k)), 'reverse', "
        "'random' (seeded), 'centre' (nearest the centre first)",
        kind="choice", choices=TIE_ORDERS, paper="section 3", tag="tie", methods=("paper",))
    boundary_diagonals: str = _option(
        "mirrored", "face diagonals of the 12 initial boundary triangles of a box: 'kuhn' or 'mirrored' (the "
        "Kuhn split mirrored in x; matches Table 1 best, the paper does not fix them)",
        kind="choice", choices=("mirrored", "kuhn"), paper="section 3, Definition 1", tag="diag", methods=INSERTING)
    vertices_in_error: bool = _option(
        True, "a tetrahedron's own four vertices (zero residual) count among its points in its error",
        kind="bool", paper="Definition 2, eqs. 14-15", tag="verr", methods=INSERTING)
    final_pass: bool = _option(
        False, "after reaching each snapshot count, swap over all tetrahedra (applied to a copy)",
        kind="bool", paper="end of section 4", tag="final", methods=INSERTING)
    first_improving: bool = _option(
        False, "apply the first improving flip of the neighbourhood O instead of the best one",
        kind="bool", paper="section 4, step (iii)", tag="first", methods=INSERTING)
    curvature: str = _option(
        "direct", "absolute-curvature estimator: 'direct' least-squares quadratic in (x, y, z), or "
        "'local-frame' (Hamann 1994b: quadratic height function over the tangent space of an estimated 4-D "
        "normal)",
        kind="choice", choices=("direct", "local-frame"), paper="section 2, eqs. 4-10", tag="curv",
        methods=("paper",))
    neighbourhood: str = _option(
        "kuhn", "points of the curvature fit: 'kuhn' edge neighbours of the initial triangulation (2-ring "
        "where rank-deficient), 'two-ring' always, or 'box' (grids: the 26 grid neighbours)",
        kind="choice", choices=("kuhn", "two-ring", "box"), paper="section 2", tag="nbhd", methods=("paper",))
    ranking: str = _option(
        "curvature", "insertion order: 'curvature' (descending K, the paper), or the diagnostic orders "
        "'ascending' (K ascending), 'random' (seeded) and 'analytic' (exact K of a Table-1 function)",
        kind="choice", choices=("curvature", "ascending", "random", "analytic"), paper="section 3", tag="rank",
        methods=("paper",))
    rel_tol: float = _option(
        1e-9, "a flip must lower the criterion sum by more than rel_tol times the sum (plus 1e-12 of the "
        "value range), so that gains at rounding level cannot cycle",
        kind="float", minimum=0.0, paper="section 4", tag="reltol", methods=INSERTING)
    quantum: float = _option(
        1e-9, "relative step to which K is rounded before sorting, so that rounding noise stays a tie (at "
        "least 1e-15: a finer step is below the curvatures' own rounding, and K / step must stay an int64)",
        kind="float", minimum=1e-15, paper="section 3", tag="quantum", methods=("paper",))
    seed: int = _option(
        0, "seed of the random tie order and of the random ranking",
        kind="int", minimum=0, tag="seed", methods=("paper",))
    greedy_key: str = _option(
        "max", "insert the point with the largest residual ('max', aims at E_inf) or the worst "
        "point of the tetrahedron with the largest squared-residual sum ('sse', aims at E_RMS)",
        kind="choice", choices=("max", "sse"), tag="gkey", methods=("greedy",))
    lazy_queue: bool = _option(
        True, "while more than twice the target count of vertices remain (and E_RMS, E_inf are "
        "below half of tol_rms, tol_inf), a vertex whose tetrahedra changed keeps its queued cost until it reaches "
        "the head of the queue; nearer the stop every changed vertex is costed again at once. False: that strict "
        "greedy order throughout (slower; the errors at the stop differ by a few percent either way)",
        kind="bool", tag="lazy", methods=("decimate",))
    block: int = _option(
        0, "decimate a grid in blocks of this many grid intervals per axis (0: in one piece), one "
        "block or region in memory at a time: one cost threshold across the blocks, then the seams freed region "
        "by region (docs/methods.md), for about 100 bytes per point besides, where one piece takes 1000. One "
        "count or fraction, and/or tol_rms (a squared-error budget the stages share) and tol_inf; not criterion "
        "'max' or candidates 'interior'",
        kind="int", minimum=0, maximum=2**31 - 1, tag="block", methods=("decimate",))
    boundary_flips: bool | None = _option(
        None, "also flip an edge between two coplanar hull faces to the other diagonal of their "
        "quadrilateral (2-2 flip), so that the boundary's triangulation adapts too",
        kind="bool", tag="bflip", methods=INSERTING)
    max_flips: int | None = _option(
        None, "at most this many flips (swap rounds) after each insertion; 0: until nothing improves "
        "(section 4). The final pass is never capped",
        kind="int", minimum=0, tag="maxflips", methods=INSERTING)
    swap_memory: str = _option(
        "run", "how long swapping remembers the configurations it evaluated: 'run' (a fixed table of about "
        "2 N entries for the whole run) or 'call' (the swaps after one insertion); identical results under "
        "'rms' and 'max', rounding-level ties may break differently under 'sse'",
        kind="choice", choices=("run", "call"), tag="mem", methods=INSERTING)
    values: tuple = _option(
        ("data",), "vertex values of the approximation: the selected points' own values ('data', the paper: a "
        "true selection) and/or least-squares values over all points on the same mesh ('fit')",
        kind="choice", choices=("data", "fit"), paper="section 5, eqs. 19-20", tag="values", sequence=True)

    def __post_init__(self):
        for f in fields(self):
            object.__setattr__(self, f.name, _check(f, getattr(self, f.name)))
        from .methods import get_method

        # a value other than the default is a setting: it must apply to the method (a
        # default given explicitly cannot be told from one left out, and changes nothing;
        # the method's own defaults, filled in by resolve(), are not settings either)
        own = get_method(self.method).DEFAULTS
        check_applicable([k for k, v in self.changed().items() if k not in own or own[k] != v], self.method)

        check_options = getattr(get_method(self.method), "check_options", None)
        if check_options is not None:
            check_options(self)

    # -- derived
    def resolve(self) -> "Options":
        """A copy with every method-dependent default (``None``) replaced by the method's value."""
        from .methods import get_method

        defaults = get_method(self.method).DEFAULTS
        return replace(self, **{k: v for k, v in defaults.items() if getattr(self, k) is None})

    def to_dict(self) -> dict:
        """Plain values (``values`` as a list), for ``result.json`` and the workflow."""
        d = asdict(self)
        d["values"] = list(d["values"])
        return d

    def changed(self) -> dict:
        """The fields that differ from the defaults, in field order."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) != f.default}

    def cli_args(self) -> list:
        """The ``trivsel reduce`` flags that reproduce these options (changed fields only)."""
        args = []
        for name, v in self.changed().items():
            f = _FIELDS[name]
            flag = _flag(f)
            if f.metadata["kind"] == "bool":
                args.append(flag if v else "--no-" + flag[2:])
            elif f.metadata["sequence"]:
                args += [flag, *map(str, v)]
            elif v is not None:
                args += [flag, repr(v) if isinstance(v, float) else str(v)]
        return args


_FIELDS = {f.name: f for f in fields(Options)}


def option_fields():
    """The dataclass fields of :class:`Options`, in order (each with its ``metadata``)."""
    return list(_FIELDS.values())


def applies(name, method) -> bool:
    """Whether the option ``name`` applies to ``method`` (its field's ``methods``)."""
    return method in method_group(name)


def method_group(name) -> tuple:
    """The methods the option ``name`` applies to, in the order of :data:`trivsel.methods.METHODS`."""
    methods = _FIELDS[name].metadata["methods"]
    if methods == INSERTING:
        from .methods import METHODS

        return tuple(n for n, m in METHODS.items() if getattr(m, "INSERTS", False))
    return methods or _method_names()


#: The method name that :func:`choose_method` resolves.
AUTO = "auto"


def choose_method(is_function: bool, given=(), *, prescribed_boundary=False) -> str:
    """What ``method="auto"`` runs: ``paper`` for a Table-1 function (the reproduction).
    For user data (grids, scattered points and tetrahedral meshes) ``decimate``, which gives
    the lowest E_RMS of trivsel's methods and beats VTK's decimation
    (``benchmarks/README.md``); then ``greedy`` (about 7x lower E_RMS than ``paper`` on
    scattered data), then ``paper``: the first that takes every option named in ``given``
    and, with ``prescribed_boundary``, a prescribed boundary."""
    from .methods import METHODS

    if is_function:
        return "paper"
    for name in ("decimate", "greedy", "paper"):
        if all(applies(k, name) for k in given if k != "method") and (METHODS[name].PRESCRIBED_BOUNDARY
                                                                       or not prescribed_boundary):
            return name
    return "decimate"


def check_applicable(names, method):
    """One-line InputError for the first option of ``names`` that does not apply to ``method``."""
    for name in names:
        if not applies(name, method):
            only = method_group(name)
            raise InputError(f"option {name} ({_flag(_FIELDS[name])}) applies to method"
                             f"{'s' if len(only) > 1 else ''} {' and '.join(only)} only, not to {method}")


def option_groups():
    """The options grouped by the methods they apply to: a list of ``(methods, fields)``,
    every method's options first, then by :data:`trivsel.methods.METHODS`' order."""
    order = _method_names()
    groups = {}
    for f in option_fields():
        groups.setdefault(method_group(f.name), []).append(f)
    return sorted(groups.items(), key=lambda g: (-len(g[0]), [order.index(m) for m in g[0]]))


def group_title(methods) -> str:
    """How ``--help`` and the docs name a group of :func:`option_groups`."""
    if tuple(methods) == _method_names():
        return "every method"
    return ("method " if len(methods) == 1 else "methods ") + " and ".join(methods) + " only"


def _choices(f):
    return _method_names() if f.name == "method" else f.metadata["choices"]


def _check(f, v):
    """One option's value, normalised, or a one-line InputError."""
    meta, name = f.metadata, f.name
    if v is None and f.default is None:
        return None
    if meta["sequence"]:
        seq = [v] if isinstance(v, str) else v
        try:
            seq = tuple(seq)
        except TypeError:
            raise InputError(f"{name} must be a list of {', '.join(_choices(f))}, got {shown(v)}") from None
        if not seq:
            raise InputError(f"{name} must name at least one of {', '.join(_choices(f))}")
        for x in seq:
            _check_choice(name, x, _choices(f))
        return tuple(dict.fromkeys(seq))
    kind = meta["kind"]
    if kind == "choice":
        _check_choice(name, v, _choices(f))
        return v
    if kind == "bool":
        import numpy as np

        if isinstance(v, (bool, np.bool_)) or (isinstance(v, numbers.Integral) and v in (0, 1)):
            return bool(v)  # a NumPy bool as a bool; 0 and 1 as a configuration file may write them
        raise InputError(f"{name} must be true or false, got {shown(v)}")
    if kind == "int":
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise InputError(f"{name} must be an integer, got {shown(v)}")
        v = int(v)
    else:
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise InputError(f"{name} must be a number, got {shown(v)}")
        v = float(v)
        if not math.isfinite(v):
            raise InputError(f"{name} must be finite, got {shown(v)}")
    if meta["minimum"] is not None and v < meta["minimum"]:
        raise InputError(f"{name} must be >= {meta['minimum']:g}, got {shown(v)}")
    if meta["maximum"] is not None and v > meta["maximum"]:
        raise InputError(f"{name} must be <= {meta['maximum']}, got {shown(v)}")
    return v


def _check_choice(name, value, choices):
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"unknown {name} {shown(value)}: choose one of {', '.join(map(str, choices))}")


# ----------------------------------------------------------------------------- command line

def _flag(f):
    return f.metadata["flag"] or "--" + f.name.replace("_", "-")


def _default_text(f):
    if f.default is None:
        return METHOD_DEFAULT
    if f.metadata["sequence"]:
        return " ".join(f.default)
    return str(f.default).lower() if isinstance(f.default, bool) else str(f.default)


def add_arguments(parser):
    """Add one flag per :class:`Options` field (``--tie-order``, ``--final-pass/--no-final-pass``, ...),
    in one argument group per set of methods they apply to (:func:`option_groups`).

    Every flag defaults to ``None`` (not given), so :func:`from_namespace` passes only
    what the user set and :class:`Options` supplies the rest."""
    for methods, group in option_groups():
        every = tuple(methods) == _method_names()
        g = parser.add_argument_group(f"options of {group_title(methods)}" + (
            " (trivsel.Options; the defaults reproduce Table 1)" if every else ""))
        for f in group:
            meta = f.metadata
            help_ = f"{meta['doc']} (default: {_default_text(f)})"
            kw = dict(dest=f.name, default=None, help=help_)
            if meta["kind"] == "bool":
                g.add_argument(_flag(f), action=argparse.BooleanOptionalAction, **kw)
            elif meta["kind"] == "choice":
                # method 'auto' is resolved by the command before Options is made
                choices = (*_choices(f), "auto") if f.name == "method" else _choices(f)
                g.add_argument(_flag(f), choices=choices, nargs="+" if meta["sequence"] else None, **kw)
            else:
                g.add_argument(_flag(f), type=int if meta["kind"] == "int" else float, **kw)


def from_namespace(ns) -> Options:
    """:class:`Options` from parsed arguments (only the flags given override the defaults);
    a flag given for a method it does not apply to is an InputError, even with its default value."""
    given = {f.name: getattr(ns, f.name) for f in option_fields() if getattr(ns, f.name, None) is not None}
    method = given.get("method", _FIELDS["method"].default)
    _check_choice("method", method, _method_names())
    check_applicable(given, method)
    return Options(**given)


# ----------------------------------------------------------------------------- workflow

def variant_tag(options: Options) -> str:
    """Directory name of an option combination: ``default``, or the changed fields as
    ``tag~value`` joined by ``_`` in field order (e.g. ``crit~max_tie~random``)."""
    changed = options.changed()
    if not changed:
        return "default"

    def text(v):
        if isinstance(v, bool):
            return "yes" if v else "no"
        if isinstance(v, tuple):
            return "+".join(v)
        return str(v).replace("_", "-")

    return "_".join(f"{_FIELDS[k].metadata['tag']}~{text(v)}" for k, v in changed.items())


def config_schema() -> dict:
    """JSON schema of the workflow's ``reduce: options:`` section: every field is a
    list of values (a sweep axis) with the field's type, choices and bounds."""
    props = {}
    for f in option_fields():
        meta = f.metadata
        if meta["kind"] == "choice":
            item = {"type": "string", "enum": list(_choices(f))}
        elif meta["kind"] == "bool":
            item = {"type": "boolean"}
        elif meta["kind"] == "int":
            item = {"type": "integer"}
        else:
            item = {"type": "number"}
        if meta["minimum"] is not None:
            item["minimum"] = meta["minimum"]
        if meta["maximum"] is not None:
            item["maximum"] = meta["maximum"]
        if meta["sequence"]:
            item = {"type": "array", "items": item, "minItems": 1, "uniqueItems": True}
        if f.default is None:
            item = {"anyOf": [item, {"type": "null"}]}
        default = list(f.default) if meta["sequence"] else f.default
        where = "" if meta["methods"] is None else f"; applies to {group_title(method_group(f.name))}"
        props[f.name] = {"type": "array", "items": item, "minItems": 1, "default": [default],
                         "description": meta["doc"] + (f" ({meta['paper']})" if meta["paper"] else "") + where}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema",
            "description": "Options of a reduction (generated from trivsel.options.Options by "
                           "`python -m trivsel.options`; do not edit). Every key is a list: a sweep axis; "
                           "null takes the method's default. A value of an option that does not apply to a "
                           "combination's method is left out of that combination (the option's default).",
            "type": "object", "properties": props, "additionalProperties": False}


# ----------------------------------------------------------------------------- docs

def options_markdown() -> str:
    """The options table of ``docs/options.md``."""
    from .methods import METHODS

    lines = ["# Options", "",
             "Generated from `trivsel.options.Options` by `python -m trivsel.options`; do not edit.",
             "Every option is a keyword of `trivsel.reduce` (and a field of `trivsel.Options`), a flag of",
             "`trivsel reduce` and a sweep axis of the workflow (`reduce: options:` in `config.yaml`).",
             "An option applies to the methods of its group: given for another method it is refused",
             "(`trivsel.Options` refuses a value other than the default; a workflow sweep leaves it out",
             "of that method's runs)."]
    for methods, group in option_groups():
        lines += ["", f"## {group_title(methods)[0].upper()}{group_title(methods)[1:]}", "",
                  "| option | flag | default | values | paper | what |", "|---|---|---|---|---|---|"]
        for f in group:
            meta = f.metadata
            flag = _flag(f)
            if meta["kind"] == "bool":
                flag = f"{flag} / --no-{flag[2:]}"
            if meta["kind"] == "choice":
                values = ", ".join(f"`{c}`" for c in _choices(f))
            elif meta["kind"] == "bool":
                values = "true, false"
            else:
                values = f"{meta['kind']} >= {meta['minimum']:g}" + (
                    f", <= {meta['maximum']}" if meta["maximum"] is not None else "")
            lines.append(f"| `{f.name}` | `{flag}` | {_default_text(f)} | {values} | {meta['paper'] or '-'} "
                         f"| {meta['doc']} |")
    lines += ["", "Method defaults (the fields shown as \"" + METHOD_DEFAULT + "\"):", ""]
    for name, module in METHODS.items():
        items = ", ".join(f"`{k}` = {v!r}" for k, v in module.DEFAULTS.items() if applies(k, name))
        lines.append(f"- `{name}`: {items}")
    return "\n".join(lines) + "\n"


def _main(argv=None):
    import json
    from pathlib import Path

    ap = argparse.ArgumentParser(prog="python -m trivsel.options",
                                 description="Write the files generated from trivsel.options.Options.")
    ap.add_argument("--root", default=".", help="repository root (default: the current folder)")
    ap.add_argument("--check", action="store_true", help="only check that the files are up to date")
    a = ap.parse_args(argv)
    root = Path(a.root)
    outputs = {root / "docs" / "options.md": options_markdown(),
               root / "workflow" / "schemas" / "options.schema.json": json.dumps(config_schema(), indent=1) + "\n"}
    stale = [p for p, text in outputs.items() if not p.exists() or p.read_text() != text]
    if a.check:
        for p in stale:
            print(f"{p} is out of date: run python -m trivsel.options")
        return 1 if stale else 0
    for p in stale:
        p.write_text(outputs[p])
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(_main())
