"""Draw the figures of docs/conventions.md: ``python docs/figures/make_figures.py [--png DIR]``.

Writes ``frames.svg`` (a pose ``T = [[R, t], [0, 1]]`` maps body coordinates to world
coordinates) and ``rotation.svg`` (active against passive rotation) next to this file, with
the text kept as text and no date, so that drawing again gives the same files.  ``--png DIR``
also writes PNG copies there, for looking at them.  Needs matplotlib (the ``bench`` extra).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Arc, FancyArrowPatch  # noqa: E402

HERE = Path(__file__).resolve().parent
X_COLOUR, Y_COLOUR, POINT, MUTED = "#c62828", "#2e7d32", "#1565c0", "#757575"
plt.rcParams.update({"svg.fonttype": "none", "svg.hashsalt": "torchlie", "font.size": 11})


def arrow(ax, start, end, colour, width=1.8, style="-|>", dashed=False) -> None:
    ax.add_patch(
        FancyArrowPatch(
            start,
            end,
            arrowstyle=style,
            mutation_scale=14,
            color=colour,
            linewidth=width,
            linestyle="--" if dashed else "-",
            shrinkA=0,
            shrinkB=0,
        )
    )


def axes_at(ax, origin, angle, length, names, dashed=False) -> None:
    """A 2-D frame (x and y axes; z out of the page) at ``origin``, turned by ``angle``."""
    ox, oy = origin
    c, s = math.cos(angle), math.sin(angle)
    for (dx, dy), colour, name in (((c, s), X_COLOUR, names[0]), ((-s, c), Y_COLOUR, names[1])):
        end = (ox + length * dx, oy + length * dy)
        arrow(ax, origin, end, colour, dashed=dashed)
        ax.annotate(
            name,
            end,
            xytext=(4 * dx - 2, 4 * dy - 2),
            textcoords="offset points",
            color=colour,
            ha="left" if dx > -0.3 else "right",
            va="bottom",
        )


def frames() -> plt.Figure:
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    theta, t = math.radians(35), (3.2, 1.4)
    axes_at(ax, (0, 0), 0, 1.6, ("$x_w$", "$y_w$"))
    ax.annotate("world", (0, 0), xytext=(-6, -14), textcoords="offset points", color=MUTED)
    axes_at(ax, t, theta, 1.3, ("$x_b$", "$y_b$"))
    ax.annotate("body", t, xytext=(-8, -16), textcoords="offset points", color=MUTED)
    arrow(ax, (0, 0), t, MUTED, width=1.2, dashed=True)
    ax.annotate(
        "$t$", (t[0] / 2, t[1] / 2), xytext=(4, -14), textcoords="offset points", color=MUTED
    )
    p_body = (1.6, 0.9)
    c, s = math.cos(theta), math.sin(theta)
    p = (t[0] + c * p_body[0] - s * p_body[1], t[1] + s * p_body[0] + c * p_body[1])
    arrow(ax, t, p, POINT, width=1.2)
    arrow(ax, (0, 0), p, POINT, width=1.2, dashed=True)
    ax.plot(*p, "o", color=POINT)
    ax.annotate("$p$", p, xytext=(6, 2), textcoords="offset points", color=POINT)
    ax.add_patch(Arc(t, 1.2, 1.2, theta1=0, theta2=math.degrees(theta), color=MUTED))
    ax.plot([t[0], t[0] + 0.9], [t[1], t[1]], ":", color=MUTED, linewidth=1)
    ax.annotate("$R$", (t[0] + 0.62, t[1] + 0.16), color=MUTED)
    ax.text(
        0.0,
        -1.05,
        "$T = [[R, t], [0, 1]]$ maps body coordinates to world coordinates:\n"
        "$p_{world} = R\\, p_{body} + t$  (T @ [p_body, 1]);  z points out of the page.",
        color="black",
        va="top",
    )
    ax.set_xlim(-0.6, 5.6)
    ax.set_ylim(-1.9, 3.9)
    ax.set_aspect("equal")
    ax.axis("off")
    return fig


def rotation() -> plt.Figure:
    fig, (left, right) = plt.subplots(1, 2, figsize=(7.6, 3.9))
    theta = math.radians(40)
    p = (1.5, 0.35)
    c, s = math.cos(theta), math.sin(theta)
    rp = (c * p[0] - s * p[1], s * p[0] + c * p[1])

    axes_at(left, (0, 0), 0, 2.0, ("$x$", "$y$"))
    arrow(left, (0, 0), p, MUTED, width=1.4)
    arrow(left, (0, 0), rp, POINT, width=2.0)
    left.annotate("$p$", p, xytext=(4, -4), textcoords="offset points", color=MUTED)
    left.annotate("$R\\,p$", rp, xytext=(2, 4), textcoords="offset points", color=POINT)
    a0 = math.degrees(math.atan2(p[1], p[0]))
    left.add_patch(Arc((0, 0), 1.5, 1.5, theta1=a0, theta2=a0 + math.degrees(theta), color=POINT))
    left.set_title(
        "active (torchlie): R @ p rotates the point;\ncoordinates in one fixed frame", fontsize=10
    )

    axes_at(right, (0, 0), 0, 2.0, ("$x$", "$y$"), dashed=True)
    axes_at(right, (0, 0), theta, 2.0, ("$x'$", "$y'$"))
    arrow(right, (0, 0), p, POINT, width=2.0)
    right.annotate("$p$", p, xytext=(4, -4), textcoords="offset points", color=POINT)
    right.add_patch(Arc((0, 0), 1.0, 1.0, theta1=0, theta2=math.degrees(theta), color=MUTED))
    right.set_title(
        "passive: the frame turns by R, the point stays;\nits new coordinates are R.T @ p",
        fontsize=10,
    )

    for ax in (left, right):
        ax.set_xlim(-1.7, 2.4)
        ax.set_ylim(-0.5, 2.3)
        ax.set_aspect("equal")
        ax.axis("off")
    fig.tight_layout()
    return fig


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--png", type=Path, default=None, help="also write PNG copies here")
    args = parser.parse_args(argv)
    for name, draw in (("frames", frames), ("rotation", rotation)):
        fig = draw()
        fig.savefig(HERE / f"{name}.svg", bbox_inches="tight", metadata={"Date": None})
        if args.png is not None:
            args.png.mkdir(parents=True, exist_ok=True)
            fig.savefig(args.png / f"{name}.png", dpi=110, bbox_inches="tight")
        plt.close(fig)


if __name__ == "__main__":
    main()
