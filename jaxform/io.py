"""Writing results: CSV tables (and, for scenes, fields through meshio)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxform.damage import CRITERIA
from jaxform.forming_outputs import damage_flags
from jaxform.postprocess import contact_profile, nodal_fields, nodal_temperature


def write_csv(path: Path, columns: dict[str, np.ndarray], fmt: str = "%.10g") -> None:
    """Write equal-length columns with a header line of their names."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt=fmt)


def read_csv(path: Path) -> dict[str, np.ndarray]:
    data = np.genfromtxt(path, delimiter=",", names=True)
    return {n: np.asarray(data[n]) for n in data.dtype.names}


def _contact_point_data(scene, fields: dict, n_nodes: int) -> dict:
    """Contact fields on the nodes (0 away from the candidates): pressure, shear traction
    (MPa), status (0 open, 1 stick, 2 slip), accumulated slip (mm)."""
    cp = contact_profile(scene, fields["x"], fields["slip_mm"], fields["contact_status"])
    nodes = np.asarray(scene.idx.contact_nodes)
    out = {}
    # a node with one candidate per die (:class:`jaxform.contact.EachDie`): the dies'
    # tractions summed, the largest status and slip
    for name, key, gather in (
        ("contact_pressure", "pressure_MPa", np.add),
        ("contact_shear", "shear_MPa", np.add),
        ("contact_status", "status", np.maximum),
        ("contact_slip", "slip_mm", np.maximum),
    ):
        v = np.zeros(n_nodes)
        gather.at(v, nodes, cp[key])
        out[name] = v
    return out


def _damage_cell_data(scene, fields: dict) -> dict:
    """Damage integrals (the largest of each element's Gauss points) and the crack-risk
    flag (1 where output.damage_critical is reached; :func:`damage_flags`)."""
    if "damage" not in fields:
        return {}
    dmg = np.asarray(fields["damage"])
    out = {f"damage_{name}": [dmg[..., i].max(axis=1)] for i, name in enumerate(CRITERIA)}
    o = scene.settings.output
    out["damage_flag"] = [damage_flags(dmg, o.damage_critical, o.damage_criterion)]
    return out


def write_vtu_row(out_dir: Path, scene, fields: dict, k: int) -> str:
    """One row's VTU, ``fields/step_<k>.vtu`` under ``out_dir``, on its own mesh
    (``scene``, the row's: after a remesh the points are the new mesh's, the deformed
    shape when it was made, and the displacement counts from there); ``fields`` the
    row's output fields (:data:`jaxform.simulation.FIELD_KEYS`).  Returns the file's
    name relative to ``out_dir``.

    Point data: displacement (mm, 3 components, the third 0), pressure (MPa; nodal for
    q1q1), temperature_K (K; coupled thermal runs), contact pressure / shear traction
    (MPa), contact status and slip (mm). Cell data (averages of the 4 Gauss points):
    Cauchy stress components (MPa), pressure (MPa), equivalent plastic strain,
    deformation resistance s (MPa); damage integrals damage_cl, damage_brozzo,
    damage_ayada (largest Gauss point) and damage_flag (1: output.damage_critical reached).
    """
    import meshio

    (Path(out_dir) / "fields").mkdir(parents=True, exist_ok=True)
    coords = np.asarray(scene.inputs.coords)
    pts = np.column_stack([coords, np.zeros(len(coords))])
    cells = [("quad", np.asarray(scene.mesh.elements))]
    u, p_nodes, _ = nodal_fields(scene, fields["x"])
    stress = np.asarray(fields["stress"]).mean(axis=1)  # (n_el, 3, 3)
    p_cell = -np.trace(stress, axis1=1, axis2=2) / 3.0
    point_data = {"displacement": np.column_stack([u, np.zeros(len(u))])}
    if p_nodes is not None:
        point_data["pressure"] = p_nodes
    temp = nodal_temperature(scene, fields["x"])
    if temp is not None:
        point_data["temperature_K"] = temp
    point_data.update(_contact_point_data(scene, fields, len(u)))
    cell_data = {
        "stress_11": [stress[:, 0, 0]],
        "stress_22": [stress[:, 1, 1]],
        "stress_12": [stress[:, 0, 1]],
        "stress_33": [stress[:, 2, 2]],
        "pressure_cell": [p_cell],
        "eqps": [np.asarray(fields["eqps"]).mean(axis=1)],
        "s": [np.asarray(fields["s"]).mean(axis=1)],
    }
    cell_data.update(_damage_cell_data(scene, fields))
    name = f"fields/step_{k:05d}.vtu"
    meshio.write(
        Path(out_dir) / name, meshio.Mesh(pts, cells, point_data=point_data, cell_data=cell_data)
    )
    return name


def write_vtu_series(out_dir: Path, result, every: int = 1) -> Path:
    """ParaView fields: one VTU per written row (:func:`write_vtu_row`, each on its own
    mesh, :meth:`jaxform.simulation.Result.scene_at`) and a .pvd time series that
    indexes them."""
    entries = []
    n_rows = len(result.fields["x"])
    for k in list(range(0, n_rows, every)) + ([n_rows - 1] if (n_rows - 1) % every else []):
        fields = {name: v[k] for name, v in result.fields.items()}
        name = write_vtu_row(out_dir, result.scene_at(k), fields, k)
        entries.append((float(result.history["time_s"][k]), name))
    return write_pvd(Path(out_dir) / "fields.pvd", entries)


class VtuSeries:
    """A ParaView series written row by row as a run accepts the rows (the ``on_row`` of
    :func:`jaxform.simulation.simulate`), so that no row holds its fields for it:
    :func:`write_vtu_row` for each, :meth:`close` the .pvd index (a row that comes again
    is written again under its number)."""

    def __init__(self, out_dir: Path):
        self.out_dir = Path(out_dir)
        self.names: dict[int, str] = {}

    def __call__(self, k: int, scene, fields: dict) -> None:
        self.names[k] = write_vtu_row(self.out_dir, scene, fields, k)

    def close(self, times) -> Path:
        """``fields.pvd`` over the rows written, at their times (``times``: the history's
        ``time_s``; a row past its end, of a run that ended earlier, is left out)."""
        entries = [(float(times[k]), self.names[k]) for k in sorted(self.names) if k < len(times)]
        return write_pvd(self.out_dir / "fields.pvd", entries)


def write_flow_lines(out_dir: Path, lines, times, every: int = 1) -> Path:
    """Flow lines (:class:`jaxform.flowlines.FlowLines`) for ParaView: one VTU of line
    cells per written row (``fields/flow_lines_*.vtu``, point data ``line`` and
    ``family``: 0 a line of constant z, 1 of constant r at t = 0) and ``flow_lines.pvd``."""
    import meshio

    out_dir = Path(out_dir)
    (out_dir / "fields").mkdir(parents=True, exist_ok=True)
    cells = [("line", lines.segments())]
    data = {"line": lines.line.astype(float), "family": lines.family[lines.line].astype(float)}
    n = len(lines.points)
    rows = list(range(0, n, every)) + ([n - 1] if (n - 1) % every else [])
    entries = []
    for k in rows:
        pts = np.column_stack([lines.points[k], np.zeros(len(lines.line))])
        name = f"fields/flow_lines_{k:05d}.vtu"
        meshio.write(out_dir / name, meshio.Mesh(pts, cells, point_data=data))
        entries.append((float(times[k]), name))
    return write_pvd(out_dir / "flow_lines.pvd", entries)


def write_pvd(path: Path, entries) -> Path:
    lines = ['<?xml version="1.0"?>', '<VTKFile type="Collection" version="0.1">', "  <Collection>"]
    lines += [f'    <DataSet timestep="{t:.10g}" part="0" file="{f}"/>' for t, f in entries]
    lines += ["  </Collection>", "</VTKFile>"]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_wear(out_dir: Path, profiles: dict) -> list[Path]:
    """One ``wear_<die>.csv`` per die (s_mm, r_mm, z_mm at t = 0, wear_mm)."""
    paths = []
    for name, p in profiles.items():
        path = Path(out_dir) / f"wear_{name}.csv"
        write_csv(path, {k: p[k] for k in ("s_mm", "r_mm", "z_mm", "wear_mm")})
        paths.append(path)
    return paths
