"""The shape annotations are true: rerun the core suites with every annotation enforced.

jaxtyping's import hook wraps each public function of torchlie with a beartype check of its
``Float[Tensor, "*b 3 3"]``-style annotations.  Tests that pass deliberately bad input (the hook
would reject it before the function's own error), compile tests (the checks are Python code
that Dynamo does not trace) and gradchecks (the same functions on the same shapes as the value
tests, called thousands of times: four fifths of this run's time with them) are left out of this
run; they run normally elsewhere.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

HERE = Path(__file__).parent
SUITES = [
    "test_so3.py",
    "test_quaternion.py",
    "test_se3.py",
    "test_conversions.py",
    "test_groups.py",
    "test_statistics.py",
    "test_lie_ops.py",
    "test_so2.py",
    "test_se2.py",
]
EXCLUDE = (
    "not wrong_shape and not bad_ and not error and not raises and not compile and not gradcheck"
)


def test_annotations_hold_over_core_suites():
    files = [str(HERE / f) for f in SUITES if (HERE / f).exists()]
    assert files, "no core test suites found"
    cmd = [
        sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider",
        "--jaxtyping-packages=torchlie,beartype.beartype", "-k", EXCLUDE, *files,
    ]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=HERE.parent, timeout=900)
    tail = "\n".join(proc.stdout.splitlines()[-25:])
    assert proc.returncode == 0, tail
    assert " passed" in tail and "failed" not in tail, tail
