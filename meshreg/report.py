"""The text the command line prints about a result: summaries of a registration and of an atlas (no numerics are
imported until a summary is made)."""

from __future__ import annotations


def summary(written) -> str:
    import numpy as np

    result = written.result
    rows = [
        f"energy E       {result.energy:.6g}   (squared elastic distance, both surfaces at area 1)",
        f"distance       {result.distance:.6g}   (sqrt(E))",
    ]
    if np.isfinite(result.energy_dp):
        rows.append(f"E after DP     {result.energy_dp:.6g}")
    rows.append(
        f"residual       {result.residual:.4g}   (RMS of R c1 - c2 o h, both centred and at area 1; "
        f"{result.residual_mirrored:.4g} against the mirror image)"
    )
    rows += [f"note           {line}" for line in result.correspondence_notes()]
    rows.append(
        "rotation R     "
        + np.array2string(result.rotation, precision=4, suppress_small=True).replace("\n", "\n               ")
    )
    rows.append("time (s)       " + ", ".join(f"{k} {v:.2f}" for k, v in result.timings.items()))
    if written.reverse is not None:
        reverse = written.reverse
        rows.append(f"reverse E      {reverse.energy:.6g}   (second rotated, first reparametrized)")
        rows.append(f"mean E         {0.5 * (result.energy + reverse.energy):.6g}")
    rows.append("written        " + ", ".join(str(f) for f in written.files))
    return "\n".join(rows)


def count(k: int, noun: str) -> str:
    return f"{k} {noun}{'' if k == 1 else 's'}"


def atlas_summary(written) -> str:
    result = written.atlas
    k = len(result.explained)
    rows = [
        f"members        {len(result.names)} kept, {len(result.failures)} left out; medoid {result.medoid}",
        f"template       {result.grid[0]} x {result.grid[1]} grid ({len(result.template)} vertices, "
        f"{len(result.faces)} triangles), shared by every aligned member",
        "mean E         "
        + " -> ".join(f"{e:.4g}" for e in result.objective)
        + f"   (per iteration; kept iteration {result.params['kept_iteration']}"
        + ("" if result.params["converged"] else ", not converged: raise --max-iterations")
        + ")",
        f"karcher gap    {result.params['karcher_gap']:.3g}   (share of mean E the q-space mean would remove)",
        f"spread         {100 * result.params['spread']:.3g}% of the template's size (RMS distance of the aligned "
        "members' vertices from the mean's, sizes equalized)",
        "explained      "
        + (
            ", ".join(f"mode {m + 1} {100 * e:.1f}%" for m, e in enumerate(result.explained[: min(k, 5)]))
            if any(e > 0 for e in result.explained)
            else "no mode: the aligned members are the same shape"
        ),
        f"time (s)       total {result.timings['total']:.1f}, per member {result.timings['per_member']:.2f} "
        f"(medoid {result.timings['medoid']:.1f}, iterations {result.timings['iterations']:.1f})",
    ]
    for name, reason in result.failures.items():
        rows.append(f"left out       {name}: {reason}")
    if written.correlations is not None:
        rows.append(
            "known params   canonical correlations of modes 1-2 scores with (relief, uplift): "
            + ", ".join(f"{c:.3f}" for c in written.correlations)
        )
    shown = [f for f in written.files if f.parent.name != "aligned"]
    rows.append("written        " + ", ".join(str(f) for f in shown) + f", aligned/ ({len(result.names)} PLY)")
    return "\n".join(rows)
