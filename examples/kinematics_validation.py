"""Kinematics validation: torchlie's forward kinematics and Jacobians against pytorch-kinematics.

A thin wrapper of :func:`torchlie.kinematics.validate.validate` (also runnable as
``python -m torchlie.kinematics.validate ROBOT``): for random joint configurations within the
limits it compares every link pose and every end link's Jacobian with an exact float64
reference and with pytorch-kinematics (if installed), prints the validation reports, then a
summary of the largest errors and the speed-ups over pytorch-kinematics.

Without pytorch-kinematics only the exact reference is compared, and the example says so on
stderr.  ``--quick`` validates the sample 7-DOF arm with 200 configurations in float64 and
float32; the full run validates the three bundled robots (arm7, tree, panda) with 1000
configurations each.

Outputs, in ``--out`` (default ``examples/out/``, ignored by git):
``kinematics_validation.txt`` (the full validation reports, also printed unless ``--brief``)
and ``kinematics_validation.json`` (the summary figures).

Run: ``python examples/kinematics_validation.py [--quick] [--robots arm7 panda ...] [--out DIR]``
(``--help`` lists every option with its default).
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path

import torch

from torchlie.kinematics import SAMPLE_ROBOTS
from torchlie.kinematics.validate import validate

OUT = Path(__file__).resolve().parent / "out"


def _max(values) -> float | None:
    vals = [v for v in values if v is not None]
    return max(vals) if vals else None


def summarise(report) -> dict:
    """The figures of one :class:`~torchlie.kinematics.validate.ValidationReport`."""
    links, jacs = report.links, report.jacobians
    fig = {
        "ok": report.ok,
        "links": len(links),
        "reach_m": report.reach,
        "ref_position_m": _max(r.ref_position for r in links),
        "ref_rotation_rad": _max(r.ref_rotation for r in links),
        "ref_jacobian": _max(j.ref_error for j in jacs),
        "pk_position_m": _max(r.pk_position for r in links),
        "pk_rotation_rad": _max(r.pk_rotation for r in links),
        "pk_jacobian": _max(j.pk_error for j in jacs),
        "pk_version": report.pk_version,
        "speedup_fk": None,
        "speedup_jacobian": None,
    }
    t = report.timings
    mine, pk = t.get("torchlie float32"), t.get("pytorch_kinematics float32")
    if mine and pk:
        fig["speedup_fk"] = pk["fk"] / mine["fk"]
        fig["speedup_jacobian"] = pk["jacobian"] / mine["jacobian"]
    return fig


def _fmt(x: float | None, spec: str = ".1e") -> str:
    return "-" if x is None else format(x, spec)


def parser() -> argparse.ArgumentParser:
    """The command line (options whose default depends on ``--quick`` state both defaults)."""
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="arm7 only, 200 configurations (CI)")
    p.add_argument(
        "--robots",
        nargs="+",
        choices=tuple(SAMPLE_ROBOTS),
        default=argparse.SUPPRESS,
        help=f"bundled robots to validate (default: all of {', '.join(SAMPLE_ROBOTS)}; "
        "arm7 with --quick)",
    )
    p.add_argument(
        "--samples",
        type=int,
        default=argparse.SUPPRESS,
        help="random joint configurations per robot (default: 1000; 200 with --quick)",
    )
    p.add_argument(
        "--dtypes",
        nargs="+",
        choices=("float64", "float32"),
        default=["float64", "float32"],
        help="dtypes of torchlie's chain to validate",
    )
    p.add_argument("--brief", action="store_true", help="print only the summary")
    p.add_argument("--out", type=Path, default=OUT, help="folder for the reports and figures")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    return p


def parse(argv: list[str] | None) -> argparse.Namespace:
    cfg = parser().parse_args(argv)
    if "robots" not in cfg:
        cfg.robots = ["arm7"] if cfg.quick else list(SAMPLE_ROBOTS)
    if "samples" not in cfg:
        cfg.samples = 200 if cfg.quick else 1000
    return cfg


def main(argv: list[str] | None = None) -> dict:
    """Validate the robots; print the reports and a summary; return the figures."""
    cfg = parse(argv)
    threads = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    try:
        results = {}
        reports = io.StringIO()
        for robot in cfg.robots:
            for name in cfg.dtypes:
                out = io.StringIO()
                report = validate(
                    robot,
                    samples=cfg.samples,
                    dtype=getattr(torch, name),
                    progress=False,
                    out=out,
                )
                results[f"{robot} {name}"] = summarise(report)
                reports.write(out.getvalue() + "\n")
                if not cfg.brief:
                    print(out.getvalue())
    finally:
        torch.set_num_threads(threads)

    print(f"summary: {cfg.samples} random configurations per robot; largest errors over all links")
    head = (
        f"{'robot, torchlie dtype':<22}{'ref |dp| m':>11}{'ref |dR|':>10}{'ref |dJ|':>10}"
        f"{'pk |dp| m':>11}{'pk |dR|':>10}{'pk |dJ|':>10}{'FK x':>7}{'J x':>7}  verdict"
    )
    print(head)
    for key, f in results.items():
        print(
            f"{key:<22}{_fmt(f['ref_position_m']):>11}{_fmt(f['ref_rotation_rad']):>10}"
            f"{_fmt(f['ref_jacobian']):>10}{_fmt(f['pk_position_m']):>11}"
            f"{_fmt(f['pk_rotation_rad']):>10}{_fmt(f['pk_jacobian']):>10}"
            f"{_fmt(f['speedup_fk'], '.1f'):>7}{_fmt(f['speedup_jacobian'], '.1f'):>7}  "
            f"{'PASS' if f['ok'] else 'FAIL'}"
        )
    print("(ref: exact float64 reference; pk: pytorch-kinematics in float32; FK x / J x: speed-up")
    print(" of torchlie float32 over pytorch-kinematics, same batch, one thread)")
    if any(f["pk_version"] is None for f in results.values()):
        print(
            "kinematics_validation: pytorch-kinematics is not installed, so only the exact "
            "reference is compared (pip install 'torchlie[validate]')",
            file=sys.stderr,
        )
    ok = all(f["ok"] for f in results.values())
    fig = {"ok": ok, "samples": cfg.samples, "results": results}
    cfg.out.mkdir(parents=True, exist_ok=True)
    files = (cfg.out / "kinematics_validation.txt", cfg.out / "kinematics_validation.json")
    files[0].write_text(reports.getvalue())
    files[1].write_text(json.dumps(fig, indent=1) + "\n")
    print(f"reports saved to {files[0]}, figures to {files[1]}")
    print("PASS" if ok else "FAIL")
    return {**fig, "files": files}


if __name__ == "__main__":
    sys.exit(0 if main()["ok"] else 1)
