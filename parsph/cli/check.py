"""``parsph check``: what a run would build, without running it."""
from __future__ import annotations

import numpy as np

from decomposition.box import Box
from decomposition.exchange import migrate
from decomposition.partition import RCB
from decomposition.reduce import gather_to_root, global_sum
from parsph.scene.budget import check_budget
from parsph.scene.geometry import body_fill, fill_warnings, generate, geometry_warnings
from parsph.core.kernel import smoothing_length, support_radius
from parsph.scene.materials import PHASE_FLUID, PHASE_SOLID, PHASE_WALL
from parsph.scene.params_probes import fields_of
from parsph.scene.params_solid import geostatic_procedure
from parsph.step.pipeline import INFRASTRUCTURE, plan


def check(comm, scene) -> str:
    """Collective: a report of stages, particle counts per rank and memory (on rank 0)."""
    specs = plan(scene)
    est = check_budget(comm, scene, specs)
    d = scene.domain.particle_size
    h = smoothing_length(d)
    fields = generate(comm, scene)
    box = Box(tuple(scene.domain.lo), tuple(scene.domain.hi), tuple(scene.domain.periodic))
    rcb = RCB.build(comm, fields["x"], box)
    fields = migrate(comm, fields, rcb.owner(fields["x"]))
    phase = fields["phase"]
    counts = global_sum(comm, np.array([(phase == k).sum() for k in
                                        (PHASE_SOLID, PHASE_FLUID, PHASE_WALL)], dtype=np.int64))
    per_rank = gather_to_root(comm, len(phase))
    fills = body_fill(comm, scene, fields)
    if comm.rank != 0:
        return ""
    total = int(counts.sum())
    mib = 2.0 ** 20
    lines = [
        f"scene '{scene.name}' ({scene.source})",
        f"  {scene.domain.dim}D, particle size d = {d:g} m, h = 1.2 d = {h:g} m, "
        f"support 2h = {support_radius(h):g} m",
        f"  mode {scene.run.mode}, end time {scene.run.end_time:g} s, "
        f"frames every {scene.output.every:g} s"
        + (f", or at rest (kinetic energy below {scene.run.rest_fraction:g} of its peak for "
           f"{scene.run.rest_time:g} s)" if scene.run.rest_fraction > 0 else ""),
        f"  start: geostatic stage '{geostatic_procedure(scene)}' (docs/geostatic.md)",
        "stages of one step:",
    ]
    rows = [(n, doc) for n, doc in INFRASTRUCTURE] + [(s.name, s.doc) for s in specs]
    lines += [f"  {name:12s} {doc}" for name, doc in rows]
    lines += [
        f"particles: {total} (solid {int(counts[0])}, fluid {int(counts[1])}, "
        f"wall {int(counts[2])})",
        "per rank: " + ", ".join(f"{r}: {n}" for r, n in enumerate(per_rank)),
        f"memory (estimate): {total * est['bytes_per_particle'] / mib:.1f} MiB total, "
        f"{total * est['bytes_per_particle'] / mib / comm.size:.1f} MiB per rank "
        f"({est['bytes_per_particle']} B per particle)"
        + (f"; this node has {est['node_memory'] / 2**30:.1f} GiB" if est["node_memory"] else ""),
    ]
    lines += _fill_lines(scene, fills)
    lines += _length_lines(scene)
    lines += _probe_lines(scene)
    lines += [f"warning: {text}" for text in geometry_warnings(scene) + fill_warnings(scene, fills)]
    return "\n".join(lines)



def _fill_lines(scene, fills) -> list[str]:
    """One line per body: its particles and the extent and measure its lattice fills,
    beside its geometry's (docs/geometry.md): a body the lattice meets short or long is
    driven differently at each d (docs/slope.md)."""
    if not fills:
        return []
    dim = scene.domain.dim
    unit = "m^2" if dim == 2 else "m^3"
    out = ["bodies as filled (lattice of d; geometry as written):"]
    for f in fills:
        if f["lo"] is None:
            out.append(f"  {f['name']:12s} {f['shape']}, no particles at this d")
            continue
        span = " x ".join(f"{h - l:.4g}" for l, h in zip(f["lo"], f["hi"]))
        text = f"  {f['name']:12s} {f['shape']}, {f['particles']} particles: {span} m"
        if f["geometry_lo"] is not None:
            gspan = " x ".join(f"{h - l:.4g}" for l, h in zip(f["geometry_lo"], f["geometry_hi"]))
            text += f" (geometry {gspan} m)"
        text += f", {f['measure']:.4g} {unit}"
        if f["geometry_measure"]:
            g = f["geometry_measure"]
            text += f" (geometry {g:.4g} {unit}, {100 * (f['measure'] - g) / g:+.2f} %)"
        out.append(text)
    return out


def _length_lines(scene) -> list[str]:
    """One line per soil: its internal length and what sees it (docs/regularisation.md)."""
    out = []
    d = scene.domain.particle_size
    trigger = scene.phase_change.eps_p_limit > 0.0
    for name, m in scene.materials.items():
        if not hasattr(m, "regularisation"):
            continue
        if not m.regularised:
            out.append(f"  {name:12s} local softening and trigger (the paper's rule)")
            continue
        sees = (["softening (m = %g)" % m.nonlocal_m] if m.softens() else []) \
            + (["phase-change trigger"] if trigger else [])
        out.append(f"  {name:12s} l = {m.internal_length:g} m = {m.internal_length / d:.2g} d: "
                   + " and ".join(sees))
    return ["internal length (docs/regularisation.md):"] + out if out else []


def _probe_lines(scene) -> list[str]:
    """One line per probe: type, stations, measure, fields, interval (DIR/probes.csv)."""
    if not scene.probes:
        return []
    out = ["probes (DIR/probes.csv):"]
    for pr in scene.probes:
        n = pr.points if pr.type == "line" else 1
        what = "integrals" if pr.type == "box" else pr.measure
        every = pr.every or scene.output.probe_every or scene.output.every
        out.append(f"  {pr.name:12s} {pr.type}, {n} station{'s' * (n > 1)}, {what} over "
                   f"{'+'.join(pr.phases)}: {', '.join(fields_of(pr, scene))}; every {every:g} s")
    return out
