"""Forward kinematics of MJCF chains: torchlie vs pytorch-kinematics' MJCF chain, same run.

Both libraries load the same MJCF text through MuJoCo's compiler (``Chain.from_mjcf``,
``pytorch_kinematics.build_chain_from_mjcf``) and compute the poses of every body, float32,
one thread, batch sizes 1 000 and 100 000, timed with ``torch.utils.benchmark`` (median of
blocked runs).  pytorch-kinematics' MJCF reader takes hinge and slide joints, one per body,
and turns a hinge about a wrong point where the joint has a ``pos`` (torchlie's poses are
MuJoCo's to round-off, see ``tests/test_kinematics_mjcf.py``), so the models are written here
in the subset it reads as MuJoCo does (no package model qualifies: they have free joints,
several joints per body, joint ``pos``, or ``<include>``s it cannot resolve from text):

* ``arm7``: a serial 7-hinge arm (8 bodies);
* ``quadruped``: a torso with four 3-hinge legs and a 1-slide tail (18 bodies).

The poses of both are checked against each other before timing.  Prints a markdown table;
the ratio is pk's time / torchlie's.

    python benchmarks/bench_mjcf.py [--quick] [--sizes 1000,100000]
"""

from __future__ import annotations

import argparse
import contextlib
import io

ARM7 = """<mujoco model="arm7"><worldbody>
<body name="l1" pos="0 0 0.3"><joint name="j1" axis="0 0 1" range="-2.9 2.9"/><geom size="0.05"/>
<body name="l2" pos="0 0 0.2" euler="1.5708 0 0"><joint name="j2" axis="0 0 1" range="-1.7 1.7"/>
<geom size="0.05"/>
<body name="l3" pos="0 -0.3 0" euler="-1.5708 0 0"><joint name="j3" axis="0 0 1"/>
<geom size="0.05"/>
<body name="l4" pos="0.08 0 0.1" euler="1.5708 0 0"><joint name="j4" axis="0 0 1" range="-3 0"/>
<geom size="0.05"/>
<body name="l5" pos="-0.08 0.38 0" euler="-1.5708 0 0"><joint name="j5" axis="0 0 1"/>
<geom size="0.05"/>
<body name="l6" pos="0 0 0" euler="1.5708 0 0"><joint name="j6" axis="0 0 1" range="0 3.7"/>
<geom size="0.05"/>
<body name="l7" pos="0.09 0 0" euler="1.5708 0 0"><joint name="j7" axis="0 0 1"/><geom size="0.05"/>
</body></body></body></body></body></body></body>
</worldbody></mujoco>"""


def _quadruped() -> str:
    legs = []
    for k, (x, y) in enumerate(((0.3, 0.2), (0.3, -0.2), (-0.3, 0.2), (-0.3, -0.2))):
        legs.append(
            f'<body name="hip{k}" pos="{x} {y} 0"><joint name="abd{k}" axis="1 0 0"/>'
            f'<geom size="0.05"/><body name="thigh{k}" pos="0 0 -0.05" euler="0 0.3 0">'
            f'<joint name="hip{k}" axis="0 1 0"/><geom size="0.05"/>'
            f'<body name="shin{k}" pos="0 0 -0.25"><joint name="knee{k}" axis="0 1 0"/>'
            f'<geom size="0.05"/><body name="foot{k}" pos="0 0 -0.25"><geom size="0.03"/>'
            "</body></body></body></body>"
        )
    tail = (
        '<body name="tail" pos="-0.4 0 0"><joint name="tail" type="slide" axis="1 0 0"/>'
        '<geom size="0.03"/></body>'
    )
    return (
        '<mujoco model="quadruped"><worldbody><body name="torso" pos="0 0 0.5">'
        f'<geom size="0.1"/>{"".join(legs)}{tail}</body></worldbody></mujoco>'
    )


def _time(fn, min_run_time: float) -> float:
    import torch.utils.benchmark as tb

    t = tb.Timer(stmt="fn()", globals={"fn": fn}, num_threads=1)
    return t.blocked_autorange(min_run_time=min_run_time).median


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1000,100000")
    parser.add_argument("--quick", action="store_true", help="shorter timing runs")
    args = parser.parse_args()
    import pytorch_kinematics as pk
    import torch

    from torchlie.kinematics import Chain

    torch.set_num_threads(1)
    min_run = 0.2 if args.quick else 1.0
    sizes = [int(s) for s in args.sizes.split(",")]
    print(f"torch {torch.__version__}, pytorch_kinematics {_version()}, float32, one thread\n")
    print("| model | B | torchlie FK (ms) | pytorch-kinematics FK (ms) | ratio |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for name, xml in (("arm7", ARM7), ("quadruped", _quadruped())):
        chain = Chain.from_mjcf(xml)
        with contextlib.redirect_stderr(io.StringIO()):
            pk_chain = _pk_chain(pk, xml)
        if list(pk_chain.get_joint_parameter_names()) != list(chain.joint_names):
            raise SystemExit(f"{name}: the two libraries order the joints differently")
        for B in sizes:
            q = chain.random_configuration(B, generator=torch.Generator().manual_seed(0))
            ours, theirs = chain.forward_kinematics(q), pk_chain.forward_kinematics(q)
            for body in chain.link_names[1:]:
                err = (ours[body] - theirs[body].get_matrix()).abs().max()
                if err > 1e-4:
                    raise SystemExit(f"{name}: {body} differs by {float(err):.1e}")
            t_ours = _time(lambda q=q, c=chain: c.forward_kinematics(q), min_run)
            t_pk = _time(lambda q=q, c=pk_chain: c.forward_kinematics(q), min_run)
            print(
                f"| {name} ({len(chain.link_names)} bodies) | {B:,} | {t_ours * 1e3:.3f} | "
                f"{t_pk * 1e3:.3f} | {t_pk / t_ours:.1f}x |"
            )


def _pk_chain(pk, xml: str):
    """pytorch-kinematics' MJCF chain.  Its joint-type table is keyed by ``mjtJoint`` members,
    which MuJoCo 3.3+ no longer equates with the integer ``joint.type`` it looks up: the table
    is given the integer keys too (the same entries)."""
    from pytorch_kinematics import mjcf

    items = list(mjcf.JOINT_TYPE_MAP.items())
    mjcf.JOINT_TYPE_MAP.clear()  # (an int key equal to a member would keep the member)
    mjcf.JOINT_TYPE_MAP.update({int(k): v for k, v in items})
    return pk.build_chain_from_mjcf(xml)


def _version() -> str:
    from importlib.metadata import version

    return version("pytorch_kinematics")


if __name__ == "__main__":
    main()
