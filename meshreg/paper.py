"""Rerun the paper's ten registration pairs in several modes and tabulate E, R and time beside its numbers."""

from __future__ import annotations

import numpy as np

from .errors import InputError
from .limits import MAX_NODES
from .pipeline import register
from .rotation import angle_between
from .samples import paper_pairs

PAPER_MAX_GRID = int(MAX_NODES**0.5)


def run_paper(grid: int = 101, modes=("dp", "gd", "dp+gd", "auto"), progress: bool = False) -> list[dict]:
    """Register every pair of :func:`meshreg.samples.paper_pairs` in every mode.

    Returns
    -------
    list of dict
        One row per pair: ``name``, ``paper`` (dict of the paper's E per mode) and, per mode,
        ``E``, ``seconds`` and ``angle`` (degrees from the true rotation, NaN for different shapes).
    """
    from tqdm import tqdm

    if not isinstance(grid, int) or not 3 <= grid <= PAPER_MAX_GRID:
        raise InputError(f"grid must be an integer from 3 to {PAPER_MAX_GRID} (the paper uses 101), got {grid!r}")
    pairs = paper_pairs(grid, grid)
    rows = []
    with tqdm(total=len(pairs) * len(modes), disable=not progress, leave=False, desc="paper pairs") as bar:
        for pair in pairs:
            row = {"name": pair.name, "paper": pair.paper}
            for mode in modes:
                result = register(pair.first, pair.second, mode=mode)
                angle = angle_between(result.rotation, pair.rotation) if pair.same_shape else float("nan")
                row[mode] = {
                    "E": result.energy,
                    "seconds": result.timings["total"],
                    "angle": angle,
                    "R": result.rotation,
                }
                bar.update(1)
            rows.append(row)
    return rows


def format_table(rows: list[dict], modes) -> str:
    """A Markdown table: per pair, the paper's E and ours per mode (E / seconds / degrees off the true R)."""
    head = ["pair"]
    for mode in modes:
        head += [f"paper {mode}" if mode in ("dp", "gd", "dp+gd") else "", f"meshreg {mode}"]
    head = [h for h in head if h]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [row["name"]]
        for mode in modes:
            if mode in row["paper"]:
                cells.append(f"{row['paper'][mode]:.3g}")
            ours = row[mode]
            angle = "" if np.isnan(ours["angle"]) else f", {ours['angle']:.2g}°"
            cells.append(f"{ours['E']:.3g} ({ours['seconds']:.2f} s{angle})")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
