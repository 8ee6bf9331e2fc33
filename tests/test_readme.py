"""The README's examples run as written, and the README stays short and self-contained.

The ```python blocks are executed in a fresh namespace in a temporary folder; the ```bash
block of the "Usage" section is run line by line through ``trivsel.cli.main`` (in process, so
the numba kernels load once) in another temporary folder.  The set-up block (the two install
commands) is not run here: CI runs the test command verbatim.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
SET_UP_COMMANDS = (
    'python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[workflow]" && snakemake -c all',
    'python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[test]" && python -m pytest -n auto --maxprocesses 4',
)


def _text():
    return README.read_text(encoding="utf-8")


def _section(title):
    """The README text from the heading `## title` to the next `## ` heading."""
    parts = re.split(r"^## ", _text(), flags=re.M)
    for part in parts[1:]:
        if part.startswith(title):
            return part
    pytest.fail(f"README.md has no section '## {title}'")


def _blocks(text, lang):
    return [body for kind, body in FENCE.findall(text) if kind == lang]


def _cli_lines():
    blocks = _blocks(_section("Usage"), "bash")
    assert blocks, "the README's Usage section has no ```bash block"
    lines = []
    for block in blocks:
        for line in block.splitlines():
            line = line.split("  #", 1)[0].strip()
            if line and not line.startswith("#"):
                lines.append(line)
    return lines


@pytest.mark.slow
def test_readme_blocks_example_runs(tmp_path, monkeypatch):
    """The ```bash block of "Large volumes in blocks" runs: ``trivsel reduce --block`` writes its
    table at the count asked for, ``trivsel blocks`` the merged mesh and summary."""
    import json

    import pandas as pd

    from trivsel.cli import main
    from trivsel.selection import count_for_fraction

    lines = [ln.split("  #", 1)[0].strip() for b in _blocks(_section("Large volumes in blocks"), "bash")
             for ln in b.splitlines() if ln.strip() and not ln.strip().startswith("#")]
    assert [shlex.split(ln)[1] for ln in lines] == ["reduce", "blocks"], lines
    monkeypatch.chdir(tmp_path)
    for line in lines:
        argv = shlex.split(line)
        assert main(argv[1:]) == 0, f"README line failed: {line}"
        out = tmp_path / argv[argv.index("--out") + 1]
        if argv[1] == "reduce":
            assert "--block" in argv
            table = pd.read_csv(out / "errors.csv")
            n = int(argv[argv.index("--n") + 1])
            assert (table["n_selected"] == count_for_fraction(float(argv[argv.index("--fractions") + 1]),
                                                               (n + 1) ** 3)).all()
            continue
        summary = json.loads((out / "summary.json").read_text())
        if "--tol-inf" in argv:
            assert summary["E_inf"] <= float(argv[argv.index("--tol-inf") + 1])
        if "--fraction" in argv:
            n = int(argv[argv.index("--n") + 1])
            assert summary["vertices"] == count_for_fraction(float(argv[argv.index("--fraction") + 1]), (n + 1) ** 3)
        if "fit" in argv:
            assert summary["fit"]["E_rms"] < summary["E_rms"]
        assert (out / "mesh.pvtu").is_file() and (out / "mesh.vtu").is_file()


def test_readme_real_volume_lines_run(tmp_path, monkeypatch):
    """The ```bash block of "Real volumes" runs as written on a NIfTI scan (a smooth volume with
    noise) and stops at the count it names; the first has the lower E_RMS, the second the lower E_max."""
    import nibabel as nib
    import numpy as np
    import pandas as pd

    from trivsel.cli import main

    lines = [ln.split("  #", 1)[0].strip() for b in _blocks(_section("Real volumes"), "bash")
             for ln in b.splitlines() if ln.strip() and not ln.strip().startswith("#")]
    assert len(lines) == 2
    g = np.indices((24, 24, 22)) / 8.0
    rng = np.random.default_rng(0)
    vol = (100 * np.sin(g[0]) * np.cos(g[1] + g[2]) + rng.normal(0, 5, g.shape[1:])).astype(np.float32)
    nib.save(nib.Nifti1Image(vol, np.diag([1.0, 1.0, 1.2, 1.0])), str(tmp_path / "scan.nii.gz"))
    monkeypatch.chdir(tmp_path)
    errors = []
    for line in lines:
        argv = shlex.split(line)
        assert argv[:2] == ["trivsel", "reduce"], line
        assert main(argv[1:]) == 0, f"README line failed: {line}"
        table = pd.read_csv(tmp_path / argv[argv.index("--out") + 1] / "errors.csv")
        assert (table["n_selected"] == int(argv[argv.index("--count") + 1])).all() and len(table) == 1
        errors.append(table.iloc[0])
    low_rms, low_max = errors
    assert low_rms["E_rms"] < low_max["E_rms"] and low_max["E_inf"] < low_rms["E_inf"]


def test_readme_python_examples_run(tmp_path, monkeypatch, capsys):
    blocks = _blocks(_text(), "python")
    assert blocks, "README.md has no ```python block"
    monkeypatch.chdir(tmp_path)
    for i, code in enumerate(blocks):
        namespace = {"__name__": f"readme_example_{i}"}
        exec(compile(code, f"README.md python block {i + 1}", "exec"), namespace)
    out = capsys.readouterr().out
    assert out.strip(), "the README's Python example printed nothing"


def test_readme_cli_examples_run(tmp_path, monkeypatch):
    from trivsel.cli import main

    lines = _cli_lines()
    assert lines, "the README's Usage ```bash block has no command"
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    for line in lines:
        argv = shlex.split(line)
        assert argv[0] == "trivsel", f"README usage line does not start with `trivsel`: {line}"
        assert main(argv[1:]) in (0, None), f"README usage line failed: {line}"
        out = next((argv[j + 1] for j, a in enumerate(argv[:-1]) if a == "--out"), None)
        if out is not None:
            assert (tmp_path / out / "errors.csv").is_file(), f"{line}: no {out}/errors.csv"
            assert list((tmp_path / out).glob("mesh_*.vtu")), f"{line}: no mesh in {out}"


def test_readme_set_up_commands_verbatim():
    """CI runs command 2 character for character; command 1 is the reproduction."""
    text = _text()
    for command in SET_UP_COMMANDS:
        assert f"\n{command}\n" in text, f"README.md lost the set-up command: {command}"


def test_ci_runs_the_readme_test_command_from_a_fresh_venv():
    """.ci/run makes a fresh venv (the old one removed, nothing installed by hand before it) and
    runs the README's test command as one line, character for character."""
    lines = (README.parent / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    command = SET_UP_COMMANDS[1]
    assert command in lines, ".ci/run does not run the README's test command verbatim"
    before = lines[:lines.index(command)]
    assert "rm -rf .venv" in before
    assert not any(w in ln for ln in before if not ln.lstrip().startswith("#") for w in ("pip ", "apt-get"))


def test_readme_is_short_and_self_contained():
    text = _text()
    n_lines = len(text.splitlines())
    assert n_lines <= 160, f"README.md has {n_lines} lines (at most 160)"
    assert not re.search(r"\bissue\s+#?\d+", text, re.I), "README.md mentions an issue number"
    assert "@@" not in text, "README.md has an unfilled placeholder"
    assert "../" not in text, "README.md points outside the repository (a path with ../)"
    assert not re.search(r"\]\((results/|\./results/)", text), "README.md links to results/ files a clone lacks"
    for marker in ("<!-- BEGIN table1: generated by `snakemake -c all readme` -->", "<!-- END table1 -->"):
        assert marker in text, f"README.md lost the generated-block marker {marker}"


def test_readme_links_exist():
    root = README.parent
    for target in re.findall(r"\]\(([^)#\s]+)\)", _text()):
        if "://" in target:
            continue
        assert (root / target).exists(), f"README.md links to a missing file: {target}"
