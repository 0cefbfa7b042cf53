# SPDX-License-Identifier: Apache-2.0
"""The README's and docs/python.md's Python code, executed as written on small data,
so that the documents cannot rot: every ```python block of a document runs in one
namespace, in order (doctest prompts stripped; the printed outputs are op1's and
are not compared). Small data: a synthetic stack stands in for op1_neuron.tif, a
quick CLI fit for op1_20k.ply, and the budgets and counts below are shrunk."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import hisnegs

HISNEGS = os.environ.get("HISNEGS_EXE", "hisnegs")
ROOT = Path(__file__).resolve().parents[2]

# What the documents' op1 figures become on the small stack.
SHRINK = [
    (r"time_budget_s=\d+", "time_budget_s=2"),
    (r"gaussians=\d+", "gaussians=150"),
    (r"budget_s=\d+", "budget_s=1"),
    (r'"maxiter": \d+', '"maxiter": 5'),
]


def python_blocks(document):
    """The code of each ```python block: doctest lines (>>> and ...) when it has
    prompts, else every line."""
    text = (ROOT / document).read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, document + " has no python block"
    code = []
    for block in blocks:
        lines = block.splitlines()
        if any(line.startswith(">>> ") for line in lines):
            lines = [line[4:] for line in lines if line.startswith((">>> ", "... "))]
        code.append("\n".join(lines))
    return code


@pytest.fixture(scope="module")
def op1(tmp_path_factory):
    d = tmp_path_factory.mktemp("docs")
    run = lambda *args: subprocess.run([HISNEGS, "-q", *map(str, args)], cwd=d, capture_output=True, text=True)
    assert run("synth", "-o", d / "op1_neuron.tif", "--shape", "16,48,48").returncode == 0
    (d / "fit.yaml").write_text("gmf: {gaussians: 150, rounds: 2, iterations_per_round: 5, time_budget_s: 0}\n")
    done = run("--config", d / "fit.yaml", "fit", d / "op1_neuron.tif", "-o", d / "op1_20k.ply")
    assert done.returncode == 0, done.stderr
    return d


@pytest.mark.parametrize("document", ["README.md", "docs/python.md"])
def test_the_documents_python_runs_as_written(document, op1, monkeypatch):
    pytest.importorskip("scipy.optimize")
    monkeypatch.chdir(op1)
    namespace = {}
    for i, code in enumerate(python_blocks(document)):
        for pattern, small in SHRINK:
            code = re.sub(pattern, small, code)
        try:
            exec(compile(code, "%s, python block %d" % (document, i + 1), "exec"), namespace)
        except Exception as e:  # noqa: BLE001  (any failure of the document's code fails the test)
            pytest.fail("%s, python block %d: %s: %s\n%s" % (document, i + 1, type(e).__name__, e, code))
    assert isinstance(namespace.get("model"), hisnegs.Model)


def test_a_package_without_its_compiled_module_says_how_to_build_it(tmp_path):
    package = tmp_path / "hisnegs"
    package.mkdir()
    (package / "__init__.py").write_text(Path(hisnegs.__file__).read_text())
    done = subprocess.run([sys.executable, "-c", "import hisnegs"], cwd=tmp_path, capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(tmp_path)))
    assert done.returncode != 0
    last = done.stderr.strip().splitlines()[-1]
    assert "the compiled module _hisnegs is not built: run `cmake --build --preset release --target hisnegs_python`" \
        in last, done.stderr
    assert "circular import" not in done.stderr
