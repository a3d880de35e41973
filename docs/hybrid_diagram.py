"""Draws docs/hybrid.png, the data flow of hybrid_localizer: python docs/hybrid_diagram.py"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch  # noqa: E402

BOXES = {
    "scan": (0.5, 6.0, "/scan, /odom", "#eeeeee"),
    "mcl": (4.5, 6.0, "MCL filter (mcl.*)\ntracking, rivals\n(weighed by each image too)", "#cfe2f3"),
    "pil": (0.5, 3.6, "PIL global_fix (pil.*)\nin the update at start and while LOST,\na worker thread while tracking", "#d9ead3"),
    "ir": (0.5, 1.2, "IR global_fix (ir.*)\nworker thread, one query at a time", "#d9ead3"),
    "score": (4.5, 2.4, "one score: the filter's scan fit\n+ the images' IMA likelihood\n(log-odds over the estimate)",
              "#fff2cc"),
    "use": (8.5, 2.4, "start: seed around the best\nrecovery: CUSUM -> inject\nambiguity: rival place -> AMBIGUOUS", "#fce5cd"),
    "ial": (8.5, 6.0, "IAL boxes from /scan (ial.*),\noptional integrity monitor:\noutside every box -> not LOCALIZED", "#ead1dc"),
    "camera": (4.5, -1.2, "camera/image_raw (camera_topomap set):\nIMA match (ima.*) against its places,\n"
               "MATCH as the likelihood there", "#d0e0e3"),
    "out": (12.3, 4.2, "~/pose, /tf, ~/candidates,\n/diagnostics (state)", "#eeeeee"),
}
ARROWS = [("scan", "mcl"), ("scan", "pil"), ("scan", "ir"), ("pil", "score"), ("ir", "score"), ("mcl", "score"),
          ("score", "use"), ("use", "mcl"), ("mcl", "out"), ("use", "out"), ("ial", "out"), ("camera", "score"),
          ("camera", "mcl")]
WIDTH, HEIGHT = 3.4, 1.6


def anchor(name: str, towards: str) -> tuple[float, float]:
    """The middle of the side of box ``name`` that faces box ``towards``."""
    x, y, _, _ = BOXES[name]
    tx, ty, _, _ = BOXES[towards]
    dx, dy = tx - x, ty - y
    if abs(dx) >= abs(dy):
        return (x + WIDTH + 0.1, y + HEIGHT / 2) if dx > 0 else (x - 0.1, y + HEIGHT / 2)
    return (x + WIDTH / 2, y + HEIGHT + 0.1) if dy > 0 else (x + WIDTH / 2, y - 0.1)


def main() -> None:
    fig, ax = plt.subplots(figsize=(12, 7.5))
    for x, y, text, colour in BOXES.values():
        ax.add_patch(FancyBboxPatch((x, y), WIDTH, HEIGHT, boxstyle="round,pad=0.05", fc=colour, ec="#444444"))
        ax.text(x + WIDTH / 2, y + HEIGHT / 2, text, ha="center", va="center", fontsize=8.5)
    for start, end in ARROWS:
        if (start, end) == ("scan", "ir"):  # around the PIL box, on the left
            ends = ((BOXES[start][0] - 0.1, BOXES[start][1] + 0.4), (BOXES[end][0] - 0.1, BOXES[end][1] + 1.2))
            style = "arc3,rad=0.35"
        elif (start, end) == ("camera", "mcl"):  # up the gap right of the score box
            ends = ((BOXES[start][0] + WIDTH + 0.1, BOXES[start][1] + 0.8), (BOXES[end][0] + WIDTH - 0.1, BOXES[end][1] - 0.1))
            style = "arc3,rad=0.12"
        else:
            ends, style = (anchor(start, end), anchor(end, start)), "arc3,rad=0"
        ax.add_patch(FancyArrowPatch(*ends, arrowstyle="-|>", mutation_scale=12, color="#555555", shrinkA=0,
                                     shrinkB=0, connectionstyle=style))
    ax.set_xlim(-0.6, 16)
    ax.set_ylim(-1.6, 8.0)
    ax.axis("off")
    ax.set_title("hybrid_localizer: the MCL filter tracks; PIL and IR propose; the camera tells look-alikes apart; "
                 "one score decides", fontsize=11)
    fig.tight_layout()
    fig.savefig(Path(__file__).with_name("hybrid.png"), dpi=110)


if __name__ == "__main__":
    main()
