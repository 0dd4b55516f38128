"""An interactive page of a mesh registration: one self-contained HTML file that works offline.

Both meshes side by side, coloured so that corresponding points share a colour, the second in the first's pose;
the two cameras move together; hovering a point of either mesh marks its match on the other (and says how far the
match lies from the hovered point once both are in the same pose). plotly's wheel carries its JavaScript, which is
embedded in the page, so nothing is fetched when it is opened.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .errors import InputError

_SCRIPT = """
var gd = document.getElementById('{plot_id}');
var matches = [__FIRST__, __SECOND__];  // matches[k][i]: the point matched with vertex i of mesh k, or null
var syncing = false;
function mark(trace, p) {
  if (p === null) { Plotly.restyle(gd, {visible: false}, [trace]); return; }
  Plotly.restyle(gd, {x: [[p[0]]], y: [[p[1]]], z: [[p[2]]], visible: true}, [trace]);
}
gd.on('plotly_hover', function (ev) {
  var p = ev.points[0];
  if (p.curveNumber > 1) { return; }
  var other = 1 - p.curveNumber;
  mark(2 + p.curveNumber, [p.x, p.y, p.z]);
  mark(2 + other, matches[p.curveNumber][p.pointNumber]);
});
gd.on('plotly_relayout', function (ev) {
  if (syncing) { return; }
  var pairs = [['scene.camera', 'scene2.camera'], ['scene2.camera', 'scene.camera']];
  for (var k = 0; k < 2; k++) {
    if (ev[pairs[k][0]]) {
      var update = {};
      update[pairs[k][1]] = ev[pairs[k][0]];
      syncing = true;
      Plotly.relayout(gd, update).then(function () { syncing = false; });
      return;
    }
  }
});
"""


def write_view(
    path,
    first: tuple[np.ndarray, np.ndarray, np.ndarray],
    second: tuple[np.ndarray, np.ndarray, np.ndarray],
    matches: tuple[np.ndarray, np.ndarray],
    second_to_first: np.ndarray | None = None,
    title: str = "",
) -> Path:
    """Write the interactive page of a mesh registration.

    Parameters
    ----------
    path : str or Path
        The HTML file.
    first, second : (vertices (n, 3), faces (m, 3), colours (n, 3) in [0, 1])
        The two meshes as given, coloured by correspondence.
    matches : (ndarray (n1, 3), ndarray (n2, 3))
        For each vertex of the first mesh its matched point on the second (in the second's coordinates), and for
        each vertex of the second its matched point on the first; NaN rows have no match.
    second_to_first : ndarray, shape (4, 4), optional
        The similarity from the second's frame to the first's: the second mesh and the matches on it are shown
        in the first's pose.
    title : str

    Returns
    -------
    Path
    """
    try:
        import plotly.graph_objects as go
        from plotly.subplots import make_subplots
    except ImportError:
        raise InputError("the interactive page needs plotly: pip install plotly") from None
    move = np.eye(4) if second_to_first is None else np.asarray(second_to_first, dtype=float)
    (v1, f1, c1), (v2, f2, c2) = first, second
    v2 = _moved(v2, move)
    on_second, on_first = _moved(matches[0], move), np.asarray(matches[1], dtype=float)
    fig = make_subplots(
        rows=1,
        cols=2,
        specs=[[{"type": "scene"}, {"type": "scene"}]],
        subplot_titles=(f"first mesh ({len(v1)} vertices)", f"second mesh ({len(v2)} vertices), in the first's pose"),
        horizontal_spacing=0.02,
    )
    for k, (v, f, c) in enumerate(((v1, f1, c1), (v2, f2, c2))):
        fig.add_trace(_mesh(go, v, f, c, ("first", "second")[k]), row=1, col=k + 1)
    for k in range(2):
        marker = dict(size=7, color="black", line=dict(color="white", width=2))
        trace = go.Scatter3d(x=[0], y=[0], z=[0], mode="markers", marker=marker, visible=False, hoverinfo="skip")
        fig.add_trace(trace, row=1, col=k + 1)
    scene = dict(
        aspectmode="data",
        xaxis_visible=False,
        yaxis_visible=False,
        zaxis_visible=False,
        camera=dict(eye=dict(x=1.5, y=-1.5, z=1.6)),
    )
    fig.update_layout(
        title=title or "corresponding points share a colour; hover a point to see its match",
        scene=scene,
        scene2=scene,
        showlegend=False,
        margin=dict(l=0, r=0, t=60, b=0),
        height=650,
    )
    script = _SCRIPT.replace("__FIRST__", _points_json(on_second)).replace("__SECOND__", _points_json(on_first))
    path = Path(path)
    fig.write_html(path, include_plotlyjs=True, full_html=True, post_script=script, config={"displaylogo": False})
    return path


def _moved(points: np.ndarray, transform: np.ndarray) -> np.ndarray:
    points = np.asarray(points, dtype=float)
    return points @ transform[:3, :3].T + transform[:3, 3]


def _mesh(go, v: np.ndarray, f: np.ndarray, colors: np.ndarray, name: str):
    rgb = [f"rgb({r},{g},{b})" for r, g, b in np.clip(np.round(np.asarray(colors) * 255), 0, 255).astype(int)]
    return go.Mesh3d(
        x=v[:, 0],
        y=v[:, 1],
        z=v[:, 2],
        i=f[:, 0],
        j=f[:, 1],
        k=f[:, 2],
        vertexcolor=rgb,
        name=name,
        hovertemplate=f"{name} mesh, vertex %{{pointNumber}}<extra></extra>",
        lighting=dict(ambient=0.55, diffuse=0.7, specular=0.15, roughness=0.6),
        flatshading=False,
    )


def _points_json(points: np.ndarray) -> str:
    """A JSON array of [x, y, z] (6 significant digits) or null for NaN rows."""
    rows = [None if not np.all(np.isfinite(p)) else [float(f"{x:.6g}") for x in p] for p in points]
    return json.dumps(rows, separators=(",", ":"))
